#!/usr/bin/env bash
# Runs the test suite. Two tiers:
#   bash scripts/test.sh           the full suite (CI, and before pushing): sets everything up first
#                                  (scripts/setup.sh), then every test
#   bash scripts/test.sh --quick   the everyday run after a change: a representative subset, every package,
#                                  under 4 minutes on 2 cores; the tests marked slow (@pytest.mark.slow in
#                                  their own files) are left to the full run. Sets up only a missing environment.
# The tests run on HOLO_TEST_WORKERS pytest-xdist workers (default 2, this project's machines' cores), a test module
# per worker; HOLO_TEST_WORKERS=0 runs them in this process.
# Other arguments go to pytest (e.g. a test file, -x, -k NAME). Output written by native code (Dr.Jit, LLVM,
# Mitsuba) goes straight to the terminal (--capture=sys): when such code aborts the process, its own last message
# is then in the log beside Python's traceback instead of lost with pytest's captured file descriptors.
set -euo pipefail
cd "$(dirname "$0")/.."
workers=(-n "${HOLO_TEST_WORKERS:-2}" --dist loadfile)
quick=0
args=()
for a in "$@"; do
  if [ "$a" = "--quick" ]; then quick=1; else args+=("$a"); fi
done
if [ "$quick" = 1 ]; then
  # set up again also when the install predates the plug-in entry points the built-ins are found by
  if ! .venv/bin/python -c "import holocore, mitsuba, torch, xdist; from importlib.metadata import entry_points as e; \
assert e(group='holocore.baselines') and e(group='display_agent.slm')" >/dev/null 2>&1; then bash scripts/setup.sh; fi
  exec .venv/bin/python -m pytest -q --capture=sys "${workers[@]}" -m "not slow" ${args[@]+"${args[@]}"}
fi
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q --capture=sys "${workers[@]}" ${args[@]+"${args[@]}"}
