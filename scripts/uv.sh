#!/usr/bin/env bash
# Print the path of the project's uv (the version lock/uv.txt pins), installing it first, hash-
# checked, into a tool venv of its own (~/.cache/armnet/uv; ARMNET_UV_DIR moves it). uv compiles
# the lock (scripts/lock.sh) and installs the venv from it (scripts/setup.d/10-python.sh).
#   uv="$(bash scripts/uv.sh)"
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dir="${ARMNET_UV_DIR:-$HOME/.cache/armnet/uv}"
want="$(grep -o '^uv==[^ ]*' "$repo/lock/uv.txt")"
have="$("$dir/bin/uv" --version 2>/dev/null | awk '{print "uv==" $2}' || true)"
if [ "$have" != "$want" ]; then
  echo "[uv] installing $want into $dir" >&2
  [ -x "$dir/bin/python" ] || python3 -m venv "$dir"
  "$dir/bin/python" -m pip install -q --disable-pip-version-check --require-hashes --no-deps \
    -r "$repo/lock/uv.txt" >&2
fi
echo "$dir/bin/uv"
