# Shared by workflow-check.sh and slurm-local.sh (sourced, not run): Snakemake in a virtual
# environment, and the reference report of one process.

# snakemake_venv VENV PACKAGE...: installs the packages into VENV (made if missing); sets SMK.
snakemake_venv() {
  local venv=$1
  shift
  if [ ! -x "$venv/bin/python" ]; then python3 -m venv "$venv"; fi
  "$venv/bin/pip" install -q "$@"
  SMK=$(realpath "$venv/bin/snakemake")
}

# one_process_report HILO PROFILE DIR: `hilo study --profile PROFILE --out DIR` in one process,
# timed; its log in DIR.log, whose tail is shown on failure.
one_process_report() {
  local hilo=$1 profile=$2 dir=$3 start
  echo "+ hilo study --profile $profile (one process)"
  start=$(date +%s)
  "$hilo" study --profile "$profile" --out "$dir" 2> "$dir.log" || { tail -20 "$dir.log"; return 1; }
  echo "  $(( $(date +%s) - start )) s"
}

# check_setup DEFAULT_PROFILE [HILO] [PROFILE]: the common start of a check: sets HILO (absolute;
# default target/release/hilo), PROFILE, SMK (Snakemake from $SNAKEMAKE_VENV or .venv-snakemake)
# and WORK (a temporary folder removed on exit).
check_setup() {
  local default_profile=$1
  HILO=$(realpath "${2:-target/release/hilo}")
  PROFILE=${3:-$default_profile}
  snakemake_venv "${SNAKEMAKE_VENV:-.venv-snakemake}" "snakemake==9.27.1"
  WORK=$(mktemp -d)
  trap 'rm -rf "$WORK"' EXIT
}
