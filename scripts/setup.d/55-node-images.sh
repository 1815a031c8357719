#!/usr/bin/env bash
# The images the test-bed node's pods run (the chart's install: the operator and agent images
# under one tag, the example and bus-loop customer images; the node's pause and base images),
# imported into the node's persistent containerd store (~/.cache/armnet/node/containerd) by a
# containerd of setup's own, so that no test session saves and imports ~6 GB beside the
# others (testbed/armnet_testbed/release_images.py). A warm run whose images did not change imports
# nothing. Only when ARMNET_SETUP_IMAGES=1 (the test command), after 50-images.sh.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"
sock_dir="$(mktemp -d /tmp/armnet-node-images.XXXXXX)"
podman system service --time=0 "unix://$sock_dir/podman.sock" &
service_pid=$!
trap 'kill "$service_pid" 2>/dev/null; wait "$service_pid" 2>/dev/null; rm -rf "$sock_dir"' EXIT
for _ in $(seq 50); do [ -S "$sock_dir/podman.sock" ] && break; sleep 0.2; done
cd "$here"
PYTHONPATH="$here/testbed${PYTHONPATH:+:$PYTHONPATH}" "$venv/bin/python" -m armnet_testbed.release_images \
  --engine "unix://$sock_dir/podman.sock"
