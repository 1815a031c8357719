#!/usr/bin/env bash
# Build the shipped images (images/runtime, images/operator, images/agent) and print
# their sizes. Usage:
#   scripts/build-images.sh                       # runtime operator agent, on the test bed's base
#   scripts/build-images.sh runtime-lerobot       # the runtime base with LeRobot (LEROBOT=1)
#   scripts/build-images.sh --base docker.io/library/python:3.11-slim --version 0.1.0
#   DOCKER_HOST=unix:///run/podman/podman.sock scripts/build-images.sh   # another engine
# Images are tagged localhost/armnet-<name>:<content hash> and :dev; an unchanged
# image is not rebuilt. Push them with e.g.
#   podman tag localhost/armnet-operator:dev registry.example.com/armnet/armnet-operator:0.1.0
#   podman push registry.example.com/armnet/armnet-operator:0.1.0
# The dependency wheels are fetched once with this venv's pip (PyPI) into
# ~/.cache/armnet/wheelhouse; the image builds themselves run without network.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
cd "$repo"
engine_args=()
if [ -z "${DOCKER_HOST:-}" ] && [ ! -S /run/podman/podman.sock ]; then
  # No engine socket: a private Podman API service for the length of this script.
  sock_dir="$(mktemp -d /tmp/armnet-build-images.XXXXXX)"
  podman system service --time=0 "unix://$sock_dir/podman.sock" &
  service_pid=$!
  trap 'kill "$service_pid" 2>/dev/null; rm -rf "$sock_dir"' EXIT
  for _ in $(seq 50); do [ -S "$sock_dir/podman.sock" ] && break; sleep 0.2; done
  engine_args=(--engine "unix://$sock_dir/podman.sock")
fi
PYTHONPATH="$repo/testbed${PYTHONPATH:+:$PYTHONPATH}" "$venv/bin/python" -m armnet_testbed.shipped_images \
  "${engine_args[@]}" "$@"
