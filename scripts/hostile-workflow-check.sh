#!/usr/bin/env bash
# A workflow written for hostile names runs hilo and nothing else: the study folder's name holds
# a newline followed by Python, quotes, `$(...)`, backticks and spaces, and so does the path of
# the hilo executable. Snakemake parses the Snakefile (a dry run executes any Python smuggled
# into it) and then runs the place rule for real through the hostile executable path; the check
# fails if a file named INJECTED appears anywhere, or if the rule did not run hilo.
#
# Usage: scripts/hostile-workflow-check.sh [HILO]   (default: target/release/hilo)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/study-check-lib.sh
check_setup tiny "$@"

# Shell that would create INJECTED in the working folder through $(...) and backticks; quotes
# and a backslash; and, after a newline (the end of a comment line), a line of Python that would
# do the same, with `#` after it so that the rest of the line stays a valid comment.
sh='$(touch INJECTED) `touch INJECTED`'
quotes=$'q\'s"d\\'
py=$'\nimport os; os.system("touch INJECTED")\n#'
out="$WORK/study ${quotes} ${sh}${py} end"
bin="$WORK/bin ${quotes} ${sh}"
mkdir -p "$bin"
cp "$HILO" "$bin/hilo"

# injected STEP: fails if a file named INJECTED appeared anywhere in the work folder.
injected() {
  local found
  found=$(find "$WORK" -name INJECTED | head -n 3)
  if [ -n "$found" ]; then
    echo "error: injected code ran during $1: $found" >&2
    exit 1
  fi
}

echo "+ hilo study --profile tiny --workflow snakemake --out <hostile name>, from a hostile path"
"$bin/hilo" study --profile tiny --workflow snakemake --out "$out" 2> "$WORK/write.log" || { tail -5 "$WORK/write.log"; exit 1; }
cd "$out"
echo "+ snakemake -n (parses the Snakefile and config.yaml)"
"$SMK" -n --quiet > "$WORK/dry.log" 2>&1 || { tail -30 "$WORK/dry.log"; exit 1; }
injected "snakemake -n"
echo "+ snakemake --cores 1 place (runs hilo through the hostile path)"
ok=0
"$SMK" --cores 1 place > "$WORK/place.log" 2>&1 || ok=$?
injected "snakemake place"
if [ "$ok" -ne 0 ]; then tail -30 "$WORK/place.log"; exit 1; fi
cd - > /dev/null
if [ -z "$(find "$out/placements" -name "*.json" 2>/dev/null)" ]; then
  echo "error: the place rule wrote no placement" >&2
  exit 1
fi
echo "  ok: nothing injected ran; the place rule ran hilo and wrote $(find "$out/placements" -name "*.json" | wc -l) placement files"
