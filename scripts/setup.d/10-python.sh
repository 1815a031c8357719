#!/usr/bin/env bash
# Python environment: a cached venv outside the repo holding exactly the committed lock,
# lock/dev.txt (hash-checked: LeRobot 0.4.4 with its dependencies, torch 2.13.0, the
# platform's and the dev tools' dependencies), then this repository editable on top with no
# dependencies (the lock holds them). uv installs it (scripts/uv.sh: the pinned uv in a tool
# venv of its own). What is pinned and why, the declared exceptions to LeRobot's pins, and how
# to update the lock: docs/lerobot-compatibility.md. No GPU is needed.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
lock="$here/lock/dev.txt"
# The venv is synced again whenever the lock changes: the stamp holds the lock's hash.
stamp="$venv/.armnet-lock"
lock_key="$(sha256sum "$lock" | cut -c1-16)"
editable_stamp="$venv/.armnet-editable"

if [ ! -x "$venv/bin/python" ]; then
  echo "[setup/python] creating venv $venv"
  mkdir -p "$(dirname "$venv")"
  python3 -m venv "$venv"
fi
uv="$(bash "$here/scripts/uv.sh")"

if [ "$(cat "$stamp" 2>/dev/null)" != "$lock_key" ]; then
  echo "[setup/python] installing lock/dev.txt into $venv (cold: a few minutes, ~3.5 GB of wheels)"
  # sync removes what the lock does not hold, our editable installs too: redo them below.
  rm -f "$stamp" "$editable_stamp" "$venv/.armnet-deps-v2"
  "$uv" pip sync --quiet --python "$venv/bin/python" --require-hashes "$lock"
  echo "$lock_key" >"$stamp"
fi

# Bytecode for every module of the venv and of this clone, compiled once here (uv installs
# none, and with PYTHONDONTWRITEBYTECODE=1, as on CI's machines, no process ever writes one):
# without it every process compiles what it imports, each time it starts (the LeRobot bus
# import: 8.5 s of CPU against 3.0 s; an agent's imports 2.5 s against 0.8 s), and the
# suite starts ~400 of them. The images compile theirs at install (pip's default). compileall
# skips a module whose bytecode is current, so a run after the first compiles only what
# changed (the clone's edited files); the venv's is redone when the lock was synced. Before
# the editable install: its import checks below then load bytecode too.
bytecode_stamp="$venv/.armnet-bytecode"
site="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
if [ "$(cat "$bytecode_stamp" 2>/dev/null)" != "$lock_key" ]; then
  echo "[setup/python] compiling the venv's bytecode (cold: ~1 min on 2 cores)"
  started=$SECONDS
  # A module in another Python's syntax (torch's py312_intrinsics.py) does not compile:
  # compileall goes on past it, and it is never imported. The suite checks that every
  # other module got its bytecode (tests/unit/testbed/test_lock_environment.py).
  "$venv/bin/python" -m compileall -q -j 0 "$site" >/dev/null 2>&1 || true
  echo "$lock_key" >"$bytecode_stamp"
  echo "[setup/python] compiled the venv's bytecode in $((SECONDS - started)) s"
fi
sources=(runtime/src operator agent cli fms testbed)
(cd "$here" && "$venv/bin/python" -m compileall -q -j 0 "${sources[@]}" >/dev/null) \
  || { echo "[setup/python] this clone's sources do not compile: run 'python -m compileall ${sources[*]}' to see where" >&2; exit 1; }
# The editable install points the venv at this clone; it is redone (~5 s) only when the
# clone, its package metadata or its top-level packages changed since the last one
# (another clone ran setup, a package was added), or the lock was synced; the import checks
# (~7 s of CPU) run after each install.
editable_key="$(cd "$here" && { echo "$here"; cat pyproject.toml runtime/pyproject.toml
  cat testbed/pyproject.toml
  ls -d runtime/src/*/__init__.py operator/*/__init__.py agent/*/__init__.py cli/*/__init__.py fms/*/__init__.py \
    testbed/*/__init__.py; } 2>/dev/null | sha256sum | cut -c1-16)"
if [ "$(cat "$editable_stamp" 2>/dev/null)" != "$editable_key" ]; then
  echo "[setup/python] installing armnet, armnet-runtime and the test bed (editable, no dependencies: the lock holds them)"
  rm -f "$editable_stamp"
  "$uv" pip install --quiet --python "$venv/bin/python" --no-deps -e "$here/runtime" -e "$here" -e "$here/testbed"
  "$venv/bin/python" -c "import lerobot.motors.feetech, lerobot.cameras.opencv, scservo_sdk, armnet_runtime" \
    || { echo "[setup/python] LeRobot motors/cameras do not import; see docs/lerobot-compatibility.md" >&2; exit 1; }
  "$venv/bin/python" -c "from lerobot.robots.so_follower import SO101Follower; from lerobot.robots.bi_so_follower import BiSOFollower" \
    || { echo "[setup/python] LeRobot's robot classes do not import; see docs/lerobot-compatibility.md" >&2; exit 1; }
  echo "$editable_key" >"$editable_stamp"
else
  echo "[setup/python] armnet already installed (editable) from $here"
fi
# The runtime image's interpreter start hook, in this venv too: a local run's job that starts
# LeRobot's own commands (lerobot-record ...) reaches the cell through its connector, and
# lerobot-calibrate is refused, as in a job's container (armnet_runtime/lerobot/in_job.py).
# Inert outside a job; rewritten each time (one small file), so a venv synced earlier gets it.
"$venv/bin/python" -c "from armnet_runtime.lerobot.in_job import write_pth; write_pth()"
echo "[setup/python] ready: $venv"
