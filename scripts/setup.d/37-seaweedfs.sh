#!/usr/bin/env bash
# SeaweedFS (Apache-2.0) for the test bed's S3-compatible object store, where the node
# agent uploads each job's output directory: `weed`, built with `go` from the module proxy
# into ~/.cache/armnet/seaweedfs/<module version>/bin/weed.
#
# Why not `go install ...@version`: seaweedfs's go.mod has a `replace` directive (a deleted
# dependency mapped to its fork), which `go install pkg@version` refuses. The module is
# downloaded to the module cache and built as the main module from there, so its own
# go.mod and go.sum (replace included) apply unchanged. Built without cgo like the
# Kubernetes binaries (testbed/armnet_testbed/objstore.py starts it).
#
# Idempotent: a warm run checks the stamp written after a successful build (module
# version) and that the binary runs, then exits.
# GOMODCACHE/GOCACHE stay in their default locations so rebuilds are incremental.
set -euo pipefail

SEAWEEDFS_VERSION="${ARMNET_SEAWEEDFS_VERSION:-v0.0.0-20261109003541-7506e5f91cd6}"
base="${ARMNET_SEAWEEDFS_DIR:-$HOME/.cache/armnet/seaweedfs}"
bin="$base/$SEAWEEDFS_VERSION/bin"
log() { echo "[setup/seaweedfs] $*"; }

have_weed() {
  [ -x "$bin/weed" ] && [ -f "$bin/weed.stamp" ] || return 1
  [ "$(cat "$bin/weed.stamp")" = "$SEAWEEDFS_VERSION" ] || return 1
  local out  # captured first: `| grep -q` would SIGPIPE the binary and trip pipefail
  out=$("$bin/weed" version 2>/dev/null) || return 1
  [[ "$out" == *version* ]]
}

if have_weed; then
  log "weed $SEAWEEDFS_VERSION cached in $bin"
else
  command -v go >/dev/null || { log "the 'go' tool is missing: install Go >= 1.26 (https://go.dev/doc/install) and re-run scripts/setup.sh" >&2; exit 1; }
  mkdir -p "$bin"
  started=$SECONDS
  log "downloading github.com/seaweedfs/seaweedfs@$SEAWEEDFS_VERSION"
  src=$(go mod download -json "github.com/seaweedfs/seaweedfs@$SEAWEEDFS_VERSION" \
    | python3 -c 'import json,sys; print(json.load(sys.stdin)["Dir"])')
  [ -f "$src/weed/weed.go" ] || { log "no weed/weed.go in $src: is $SEAWEEDFS_VERSION a seaweedfs version?"; exit 1; }
  rm -f "$bin/weed.stamp"
  log "building weed (cold: 10-25 min on 2 cores; it links ~1500 packages)"
  # The module cache is read-only; -mod=readonly keeps go from trying to edit go.mod/go.sum there.
  (cd "$src" && CGO_ENABLED=0 nice -n 10 go build -mod=readonly -trimpath -ldflags "-s -w" \
    -o "$bin/weed.tmp" ./weed)
  mv "$bin/weed.tmp" "$bin/weed"
  echo "$SEAWEEDFS_VERSION" > "$bin/weed.stamp"
  have_weed || { log "weed does not run: $("$bin/weed" version 2>&1 || true)"; exit 1; }
  log "built weed in $((SECONDS - started)) s"
fi
echo "$SEAWEEDFS_VERSION" > "$base/current"
log "ready: $("$bin/weed" version | head -1) at $bin/weed"
