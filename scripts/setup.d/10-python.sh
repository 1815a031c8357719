#!/usr/bin/env bash
# Python environment: a cached venv outside the repo with CPU torch, LeRobot 0.4.4
# (motors + cameras only) and this repository installed editable.
# Order matters: CPU torch FIRST, or pip pulls several GB of CUDA wheels for lerobot.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
stamp="$venv/.armnet-deps-v1"

if [ ! -x "$venv/bin/python" ]; then
  echo "[setup/python] creating venv $venv"
  mkdir -p "$(dirname "$venv")"
  python3 -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip --disable-pip-version-check -q)

if [ ! -f "$stamp" ]; then
  echo "[setup/python] installing CPU torch, LeRobot 0.4.4 and their motor/camera deps (cold: a few minutes)"
  "${pip[@]}" install --upgrade pip setuptools wheel
  "${pip[@]}" install torch==2.13.0
  "${pip[@]}" install --no-deps lerobot==0.4.4
  "${pip[@]}" install -c <(echo torch==2.13.0) feetech-servo-sdk pyserial deepdiff "draccus==0.10.0" tqdm \
      "opencv-python-headless<4.13" packaging termcolor huggingface-hub numpy accelerate datasets
  touch "$stamp"
fi

echo "[setup/python] installing armnet (editable) and dev tools"
"${pip[@]}" install -c <(echo torch==2.13.0) -e "$here/runtime[fast]" -e "$here[dev]"
"$venv/bin/python" -c "import lerobot.motors.feetech, lerobot.cameras.opencv, scservo_sdk, armnet_runtime" \
  || { echo "[setup/python] LeRobot motors/cameras do not import; see shared reference lerobot-feetech.md §0" >&2; exit 1; }
echo "[setup/python] ready: $venv"
