#!/usr/bin/env bash
# Kubernetes test-bed binaries: kube-apiserver, kubectl, kubelet (one wrapper module,
# see docs/reference/testbed-host.md, "Kubernetes components") and etcd (a SEPARATE
# wrapper module, so minimal version selection cannot move the Kubernetes
# dependency set), built with the `go` tool from the module proxy into ~/.cache/armnet/k8s/v<version>/bin.
#
# Why a wrapper: k8s.io/kubernetes replaces its staging modules with local paths,
# so `go install k8s.io/kubernetes/cmd/...@v1.x` cannot work. We require the tag
# and replace every staging module with its published v0.<minor>.<patch> tag.
# Debian's etcd (3.4.23) is below the minimum supported by kube-apiserver >= 1.31.
#
# Idempotent: a warm run checks the binaries report the pinned versions and exits.
# GOMODCACHE/GOCACHE stay in their default locations so rebuilds are incremental.
set -euo pipefail

K8S_VERSION="${ARMNET_K8S_VERSION:-1.34.4}"
ETCD_VERSION="${ARMNET_ETCD_VERSION:-3.6.5}"
root="${ARMNET_K8S_DIR:-$HOME/.cache/armnet/k8s}/v$K8S_VERSION"
bin="$root/bin"
log() { echo "[setup/k8s] $*"; }

command -v go >/dev/null || { echo "[setup/k8s] the 'go' tool is missing: install Go >= 1.24 (https://go.dev/doc/install) and re-run scripts/setup.sh" >&2; exit 1; }

have() { # have <binary> <expected substring of its version output>
  local cmd=(--version)
  [ "$1" = kubectl ] && cmd=(version --client)
  [ -x "$bin/$1" ] || return 1
  local out  # captured first: `| grep -q` would SIGPIPE the binary and trip pipefail
  out=$("$bin/$1" "${cmd[@]}" 2>/dev/null) || return 1
  [[ "$out" == *"$2"* ]]
}

# go build -v prints one line per compiled package; show a line every 100 packages
# (a cold kube-apiserver build compiles ~2000) so a long build visibly progresses.
build_with_progress() { # build_with_progress <name> <go build args...>
  local name="$1"; shift
  local started=$SECONDS
  log "building $name (cold: 10-20 min on 2 cores; progress every 100 packages)"
  nice -n 10 go build -v "$@" 2>&1 | awk -v n="$name" -v t0="$started" '
    /^#|\.go:[0-9]+:|^go: / { print "[setup/k8s]   " $0; fflush(); next }
    { c++; if (c % 100 == 0) { printf "[setup/k8s]   %s: %d packages compiled\n", n, c; fflush() } }'
  local rc=${PIPESTATUS[0]}
  [ "$rc" -eq 0 ] || { log "building $name FAILED (exit $rc); see the lines above"; return "$rc"; }
  log "built $name in $((SECONDS - started)) s"
}

mkdir -p "$bin"
minor=$(echo "$K8S_VERSION" | cut -d. -f2)
ldf="-s -w"
for p in k8s.io/component-base/version k8s.io/client-go/pkg/version; do
  ldf="$ldf -X $p.gitVersion=v$K8S_VERSION -X $p.gitMajor=1 -X $p.gitMinor=$minor -X $p.gitTreeState=clean"
done

# ---------------------------------------------------------------- kube-apiserver + kubectl
if have kube-apiserver "v$K8S_VERSION" && have kubectl "v$K8S_VERSION"; then
  log "kube-apiserver and kubectl v$K8S_VERSION cached in $bin"
else
  src="$root/src/kubernetes"
  mkdir -p "$src"
  cd "$src"
  if [ ! -f go.mod ] || ! grep -q "k8s.io/kubernetes v$K8S_VERSION" go.mod; then
    log "preparing wrapper module for k8s.io/kubernetes v$K8S_VERSION (downloads ~200 modules cold)"
    rm -f go.mod go.sum
    go mod init armnet.local/k8sbins >/dev/null 2>&1
    go mod edit -go=1.24.0
    stg="v0.${K8S_VERSION#1.}"
    gomod=$(go mod download -json "k8s.io/kubernetes@v$K8S_VERSION" \
      | python3 -c 'import json,sys; print(json.load(sys.stdin)["GoMod"])')
    # Every staging module (k8s.io/<x> => ./staging/src/k8s.io/<x>) maps to its published tag.
    mapfile -t staging < <(sed -n 's|^[[:space:]]*\(replace[[:space:]]\{1,\}\)\{0,1\}\(k8s\.io/[^ ]*\) => \./staging/src/.*|\2|p' "$gomod")
    [ "${#staging[@]}" -gt 20 ] || { log "could not read the staging module list from $gomod"; exit 1; }
    for m in "${staging[@]}"; do go mod edit -replace="$m=$m@$stg"; done
    log "replaced ${#staging[@]} staging modules with $stg; resolving dependencies"
    cat > tools.go <<'EOF'
//go:build tools

// Package tools pins the commands this wrapper module builds, so `go mod tidy` keeps them.
package tools

import (
	_ "k8s.io/kubernetes/cmd/kube-apiserver"
	_ "k8s.io/kubernetes/cmd/kubectl"
	_ "k8s.io/kubernetes/cmd/kubelet"
)
EOF
    nice -n 10 go get "k8s.io/kubernetes@v$K8S_VERSION" \
      "k8s.io/kubernetes/cmd/kube-apiserver@v$K8S_VERSION" "k8s.io/kubernetes/cmd/kubectl@v$K8S_VERSION" \
      "k8s.io/kubernetes/cmd/kubelet@v$K8S_VERSION"
  fi
  export CGO_ENABLED=0
  build_with_progress kube-apiserver -trimpath -ldflags "$ldf" -o "$bin/kube-apiserver.tmp" k8s.io/kubernetes/cmd/kube-apiserver
  mv "$bin/kube-apiserver.tmp" "$bin/kube-apiserver"
  build_with_progress kubectl -trimpath -ldflags "$ldf" -o "$bin/kubectl.tmp" k8s.io/kubernetes/cmd/kubectl
  mv "$bin/kubectl.tmp" "$bin/kubectl"
  have kube-apiserver "v$K8S_VERSION" && have kubectl "v$K8S_VERSION" \
    || { log "kube-apiserver/kubectl do not report v$K8S_VERSION"; exit 1; }
fi

# ---------------------------------------------------------------- kubelet (test-bed node)
# Same wrapper module and flags as the apiserver. Its packages need their own
# `go get` first (otherwise: missing go.sum entry for github.com/google/cadvisor/...);
# a module prepared before kubelet was added gets the import and the requirements
# here, which only adds to go.mod. Built without cgo like the apiserver (docs/reference/testbed-host.md).
if have kubelet "v$K8S_VERSION"; then
  log "kubelet v$K8S_VERSION cached in $bin"
else
  cd "$root/src/kubernetes"
  if ! grep -q '"k8s.io/kubernetes/cmd/kubelet"' tools.go; then
    log "adding kubelet to the wrapper module"
    sed -i 's|^\t_ "k8s.io/kubernetes/cmd/kubectl"$|&\n\t_ "k8s.io/kubernetes/cmd/kubelet"|' tools.go
    grep -q '"k8s.io/kubernetes/cmd/kubelet"' tools.go || { log "could not add kubelet to $PWD/tools.go"; exit 1; }
    nice -n 10 go get "k8s.io/kubernetes/cmd/kubelet@v$K8S_VERSION"
  fi
  CGO_ENABLED=0 build_with_progress kubelet -trimpath -ldflags "$ldf" -o "$bin/kubelet.tmp" k8s.io/kubernetes/cmd/kubelet
  mv "$bin/kubelet.tmp" "$bin/kubelet"
  have kubelet "v$K8S_VERSION" || { log "kubelet does not report v$K8S_VERSION"; exit 1; }
fi

# ---------------------------------------------------------------- controller manager + scheduler
# Only the chart's real install on the test-bed node needs them (a Deployment and a
# DaemonSet become pods): testbed/armnet_testbed/controllers.py starts them for that test alone.
# Same wrapper module, flags and pattern as the kubelet.
for component in kube-controller-manager kube-scheduler; do
  if have "$component" "v$K8S_VERSION"; then
    log "$component v$K8S_VERSION cached in $bin"
    continue
  fi
  cd "$root/src/kubernetes"
  if ! grep -q "\"k8s.io/kubernetes/cmd/$component\"" tools.go; then
    log "adding $component to the wrapper module"
    sed -i "s|^\t_ \"k8s.io/kubernetes/cmd/kubectl\"\$|&\n\t_ \"k8s.io/kubernetes/cmd/$component\"|" tools.go
    grep -q "\"k8s.io/kubernetes/cmd/$component\"" tools.go || { log "could not add $component to $PWD/tools.go"; exit 1; }
    nice -n 10 go get "k8s.io/kubernetes/cmd/$component@v$K8S_VERSION"
  fi
  CGO_ENABLED=0 build_with_progress "$component" -trimpath -ldflags "$ldf" -o "$bin/$component.tmp" "k8s.io/kubernetes/cmd/$component"
  mv "$bin/$component.tmp" "$bin/$component"
  have "$component" "v$K8S_VERSION" || { log "$component does not report v$K8S_VERSION"; exit 1; }
done

# ---------------------------------------------------------------- etcd
if have etcd "$ETCD_VERSION"; then
  log "etcd $ETCD_VERSION cached in $bin"
else
  src="$root/src/etcd"
  mkdir -p "$src"
  cd "$src"
  if [ ! -f go.mod ] || ! grep -q "go.etcd.io/etcd/server/v3 v$ETCD_VERSION" go.mod; then
    log "preparing wrapper module for etcd v$ETCD_VERSION"
    rm -f go.mod go.sum
    go mod init armnet.local/etcdbin >/dev/null 2>&1
    cat > main.go <<'EOF'
// Command etcd is upstream's server main: etcdmain.Main, built from the tagged module.
package main

import (
	"os"

	"go.etcd.io/etcd/server/v3/etcdmain"
)

func main() { etcdmain.Main(os.Args) }
EOF
    nice -n 10 go get "go.etcd.io/etcd/server/v3@v$ETCD_VERSION"
    nice -n 10 go mod tidy
  fi
  CGO_ENABLED=0 build_with_progress etcd -trimpath -ldflags "-s -w" -o "$bin/etcd.tmp" .
  mv "$bin/etcd.tmp" "$bin/etcd"
  have etcd "$ETCD_VERSION" || { log "etcd does not report $ETCD_VERSION"; "$bin/etcd" --version || true; exit 1; }
fi

echo "$K8S_VERSION" > "${ARMNET_K8S_DIR:-$HOME/.cache/armnet/k8s}/current"
log "ready: $("$bin/kube-apiserver" --version), $("$bin/kubectl" version --client 2>/dev/null | head -1), kubelet $("$bin/kubelet" --version | awk '{print $2}'), etcd $("$bin/etcd" --version | head -1 | awk '{print $3}')"
