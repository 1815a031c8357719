#!/usr/bin/env bash
# One idempotent setup for development and CI: runs every scripts/setup.d/NN-*.sh in
# order, stops at the first failure, and prints each step with its duration.
#
# The `go` builds of the Kubernetes binaries, Helm and SeaweedFS (30-k8s, 35-helm, 37-seaweedfs:
# CPU-bound, 15-16 min cold on 2 cores, seconds warm) need only the machine's `go`, so they
# start first, in the background, while the other steps (downloads, apt, debootstrap, image
# builds: much of it disk and network) go on; their output is printed when they end. They
# are the cold setup's longest path (on a fresh machine kube-apiserver alone takes ~13 min,
# docs/benchmarks.md), so nothing waits for them to start.
# ARMNET_SETUP_IMAGES=1 (the test command sets it) adds the steps from 50 on: the shipped
# images, and their import into the test-bed node's image store.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
total_start=$SECONDS
background_steps=(30-k8s.sh 35-helm.sh 37-seaweedfs.sh)
background_pids=()
background_names=()
background_logs=()
trap 'rm -f "${background_logs[@]}"' EXIT

is_background() {
  local step
  for step in "${background_steps[@]}"; do [ "$step" = "$1" ] && return 0; done
  return 1
}

run_step() { # run_step <path>: the step with its duration; non-zero when it failed
  local name step_start
  name="$(basename "$1")"
  echo "==> [setup] $name"
  step_start=$SECONDS
  if ! bash "$1"; then
    echo "==> [setup] $name FAILED after $((SECONDS - step_start)) s" >&2
    return 1
  fi
  echo "==> [setup] $name done in $((SECONDS - step_start)) s"
}

wait_background() { # the background steps' output, in order; non-zero when one failed
  local i rc=0
  for i in "${!background_pids[@]}"; do
    wait "${background_pids[$i]}" || rc=1
    cat "${background_logs[$i]}"
  done
  background_pids=()
  return "$rc"
}

wanted() { # wanted <step name>: the steps from 50 on only with ARMNET_SETUP_IMAGES=1
  [[ "$1" < 50 ]] || [ "${ARMNET_SETUP_IMAGES:-0}" = 1 ]
}

for step in "$here"/setup.d/*.sh; do
  name="$(basename "$step")"
  if wanted "$name" && is_background "$name"; then
    log="$(mktemp /tmp/armnet-setup.XXXXXX)"
    background_logs+=("$log")
    background_names+=("$name")
    echo "==> [setup] $name started in the background"
    run_step "$step" >"$log" 2>&1 &
    background_pids+=("$!")
  fi
done
for step in "$here"/setup.d/*.sh; do
  name="$(basename "$step")"
  if ! wanted "$name" || is_background "$name"; then
    continue
  fi
  if ! run_step "$step"; then
    wait_background || true
    exit 1
  fi
done
if [ "${#background_pids[@]}" -gt 0 ]; then
  echo "==> [setup] waiting for ${background_names[*]}"
  wait_background || exit 1
fi
echo "==> [setup] all steps done in $((SECONDS - total_start)) s"
