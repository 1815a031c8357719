#!/usr/bin/env bash
# Compile the dependency lock (lock/*.txt, committed) from lock/*.in, lock/overrides.txt and
# the two pyproject files, with uv (docs/lerobot-compatibility.md, "Updating the lock").
#   scripts/lock.sh                      # after a dependency change: keep every other pin
#   scripts/lock.sh --upgrade            # move everything to the newest allowed versions
#   scripts/lock.sh --upgrade-package X  # move X (and what it needs) only
# dev.txt is the whole set (the developer and CI venv); each image's lock is compiled with
# dev.txt as constraints, so an image never holds a version the venv does not. Target: CPython
# 3.11 on x86_64 Linux, glibc 2.36 (Debian bookworm: this machine and the images' base).
# Needs the package registry; the suite only reads the result (tests/unit/testbed/test_lock.py).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
uv="$(bash scripts/uv.sh)"  # the pinned uv, in its own tool venv

compile=("$uv" pip compile --quiet --python-version 3.11 --python-platform x86_64-manylinux_2_36
         --generate-hashes --overrides lock/overrides.txt
         --no-emit-package armnet --no-emit-package armnet-runtime
         --custom-compile-command "scripts/lock.sh")
"${compile[@]}" "$@" lock/dev.in -o lock/dev.txt
"${compile[@]}" lock/uv.in -o lock/uv.txt
for image in runtime platform lerobot; do
  "${compile[@]}" -c lock/dev.txt lock/$image.in -o lock/$image.txt
done
python3 testbed/armnet_testbed/lockfile.py >lock/inputs.sha256
echo "[lock] lock/dev.txt: $(grep -c '^[a-z]' lock/dev.txt) packages;" \
     "images: $(for i in runtime platform lerobot; do printf '%s %s ' "$i" "$(grep -c '^[a-z]' lock/$i.txt)"; done)"
