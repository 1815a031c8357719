#!/usr/bin/env bash
# The shipped images (images/: runtime, operator, agent, the runtime's LeRobot variant), built
# once per content with scripts/build-images.sh; a warm run whose sources did not change
# builds nothing. Only when ARMNET_SETUP_IMAGES=1 (the test command): the test sessions then
# find them instead of building them beside timing-sensitive tests. Prints their sizes.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
exec bash "$here/scripts/build-images.sh" runtime operator agent runtime-lerobot
