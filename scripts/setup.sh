#!/usr/bin/env bash
# One idempotent setup for development and CI: runs every scripts/setup.d/NN-*.sh in
# order, stops at the first failure, and prints each step with its duration.
# Cold on 2 cores: ~25 min (mostly the Kubernetes go build); warm: seconds.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
total_start=$SECONDS
for step in "$here"/setup.d/*.sh; do
  name="$(basename "$step")"
  echo "==> [setup] $name"
  step_start=$SECONDS
  if ! bash "$step"; then
    echo "==> [setup] $name FAILED after $((SECONDS - step_start)) s" >&2
    exit 1
  fi
  echo "==> [setup] $name done in $((SECONDS - step_start)) s"
done
echo "==> [setup] all steps done in $((SECONDS - total_start)) s"
