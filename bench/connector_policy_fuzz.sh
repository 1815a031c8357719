#!/usr/bin/env bash
# The connector's fuzzers, run long: hostile jobs against the simulated SO-101, checked on the
# servos' side (tests/unit/connector/test_connector_policy_fuzz.py), and random and hostile
# request lines on its sockets, each answered well-formed (test_connector_fuzz.py).
#   bench/connector_policy_fuzz.sh            # 500 examples
#   ARMNET_FUZZ_EXAMPLES=5000 bench/connector_policy_fuzz.sh
set -euo pipefail
cd "$(dirname "$0")/.."
export ARMNET_FUZZ_EXAMPLES="${ARMNET_FUZZ_EXAMPLES:-500}"
exec python -m pytest tests/unit/connector/test_connector_policy_fuzz.py \
  tests/unit/connector/test_connector_fuzz.py -q -p no:randomly "$@"
