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
