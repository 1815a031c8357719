#!/usr/bin/env bash
# The manifest fuzzer, long: random and hostile RobotJob and Cell manifests against the
# real API server with the operator running (tests/integration/test_operator_fuzz_manifests.py).
# Usage: bench/fuzz_manifests.sh [EXAMPLES]   (default 300; the suite runs 12)
set -euo pipefail
cd "$(dirname "$0")/.."
export ARMNET_FUZZ_MANIFESTS="${1:-300}"
export PYTHONPATH="$PWD/runtime/src:$PWD/agent:$PWD/operator:$PWD/cli:$PWD"
exec "${PYTHON:-$HOME/.cache/armnet/venv/bin/python}" -m pytest -q -s -p no:cacheprovider \
  --timeout=3600 tests/integration/test_operator_fuzz_manifests.py
