#!/usr/bin/env bash
# Python environment: a cached venv outside the repo with torch, LeRobot 0.4.4 (motors,
# cameras and the robot classes: SO101Follower, BiSOFollower) and this repository editable.
# Order matters: torch FIRST, LeRobot with --no-deps (it pins torch<2.11), and every other
# install constrained to the same torch, so pip never replaces it. No GPU is needed.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
stamp="$venv/.armnet-deps-v2"  # bump when the dependency set below changes
torch_pin="torch==2.13.0"
# What lerobot.processor (imported by every robot class) needs, at the versions built for
# $torch_pin: torchvision 0.28 is the release paired with torch 2.13.
robot_deps=(torchvision==0.28.0 av==18.1.0 einops==0.8.2 pillow==13.0.0)

if [ ! -x "$venv/bin/python" ]; then
  echo "[setup/python] creating venv $venv"
  mkdir -p "$(dirname "$venv")"
  python3 -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip --disable-pip-version-check -q)

if [ ! -f "$stamp" ]; then
  echo "[setup/python] installing torch, LeRobot 0.4.4 and their motor/camera/robot deps (cold: a few minutes)"
  "${pip[@]}" install --upgrade pip setuptools wheel
  "${pip[@]}" install "$torch_pin"
  "${pip[@]}" install --no-deps lerobot==0.4.4
  "${pip[@]}" install -c <(echo "$torch_pin") feetech-servo-sdk pyserial deepdiff "draccus==0.10.0" tqdm \
      "opencv-python-headless<4.13" packaging termcolor huggingface-hub numpy accelerate datasets \
      "${robot_deps[@]}"
  touch "$stamp"
fi

# The editable install points the venv at this clone; it is redone (~15 s) only when the
# clone, its package metadata or its top-level packages changed since the last one
# (another clone ran setup, a dependency or a package was added); the import checks
# (~7 s of CPU) run after each install.
editable_stamp="$venv/.armnet-editable"
editable_key="$(cd "$here" && { echo "$here"; cat pyproject.toml runtime/pyproject.toml
  ls -d runtime/src/*/__init__.py operator/*/__init__.py agent/*/__init__.py cli/*/__init__.py fms/*/__init__.py; } 2>/dev/null | sha256sum | cut -c1-16)"
if [ "$(cat "$editable_stamp" 2>/dev/null)" != "$editable_key" ]; then
  echo "[setup/python] installing armnet (editable), rerun-sdk for armnet view, and dev tools"
  rm -f "$editable_stamp"
  "${pip[@]}" install -c <(echo "$torch_pin") -e "$here/runtime[fast,view]" -e "$here[dev]"
  "$venv/bin/python" -c "import lerobot.motors.feetech, lerobot.cameras.opencv, scservo_sdk, armnet_runtime" \
    || { echo "[setup/python] LeRobot motors/cameras do not import; see docs/lerobot-compatibility.md" >&2; exit 1; }
  "$venv/bin/python" -c "from lerobot.robots.so_follower import SO101Follower; from lerobot.robots.bi_so_follower import BiSOFollower" \
    || { echo "[setup/python] LeRobot's robot classes do not import (torchvision/av/einops/pillow?); see docs/lerobot-compatibility.md" >&2; exit 1; }
  echo "$editable_key" >"$editable_stamp"
else
  echo "[setup/python] armnet already installed (editable) from $here"
fi
echo "[setup/python] ready: $venv"
