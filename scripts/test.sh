#!/usr/bin/env bash
# The whole test suite on a fresh machine: install what is missing (cached), lint, type-check, test.
# Usage: scripts/test.sh [pytest args...]   e.g. scripts/test.sh -m unit
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"

bash scripts/setup.sh

echo "== ruff =="
"$venv/bin/ruff" check .
echo "== mypy (strict, runtime SDK) =="
"$venv/bin/mypy"
echo "== import-linter (checked layers, .importlinter) =="
"$venv/bin/lint-imports" --no-cache --no-logo
echo "== pytest =="
export PATH="$venv/bin:$PATH"
if [ "$#" -gt 0 ]; then
  exec "$venv/bin/python" -m pytest "$@"
fi

# The node agent's end-to-end scenarios spend their minutes waiting (jobs running in
# containers, timeouts, grace windows), so they run beside the rest of the suite, in a
# pytest session of their own (its own control plane, NATS and Podman service).
side_tests=(e2e/test_agent_jobs.py)
side_log="$(mktemp /tmp/armnet-test-side.XXXXXX)"
trap 'rm -f "$side_log"' EXIT
"$venv/bin/python" -m pytest "${side_tests[@]}" >"$side_log" 2>&1 &
side_pid=$!
main_rc=0
"$venv/bin/python" -m pytest "${side_tests[@]/#/--ignore=}" || main_rc=$?
side_rc=0
wait "$side_pid" || side_rc=$?
echo "== pytest: ${side_tests[*]} (run beside the rest) =="
cat "$side_log"
if [ "$main_rc" -ne 0 ] || [ "$side_rc" -ne 0 ]; then
  echo "pytest failed: suite exit $main_rc, ${side_tests[*]} exit $side_rc" >&2
  exit 1
fi
