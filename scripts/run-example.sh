#!/usr/bin/env bash
# The README's first command: install what is needed, then run the LeRobot bus-loop
# example on a simulated SO-101 cell and print its JobResult.
#   ./scripts/run-example.sh                 # Python setup (idempotent) + bus_loop.py
#   ./scripts/run-example.sh --json          # extra flags go to `armnet run`
#   ARMNET_EXAMPLE=runtime/examples/camera.py ./scripts/run-example.sh
#   ARMNET_EXAMPLE_SETUP=all ./scripts/run-example.sh   # the whole setup (Podman etc., for --image)
# A local run needs only the Python environment, so that is all it installs by default.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
example="${ARMNET_EXAMPLE:-runtime/examples/bus_loop.py}"

if [ "${ARMNET_EXAMPLE_SETUP:-python}" = "all" ]; then
  "$here/scripts/setup.sh"
else
  bash "$here/scripts/setup.d/10-python.sh"
fi

cd "$here"
echo "==> armnet run $example --embodiment lerobot/so-101 $*"
exec "$venv/bin/armnet" run "$example" --embodiment lerobot/so-101 "$@"
