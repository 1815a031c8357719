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
exec "$venv/bin/python" -m pytest "$@"
