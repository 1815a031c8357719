#!/usr/bin/env bash
# Helm v3 for the chart tests (helm lint / template / install), built with `go` from
# the module proxy into ~/.cache/armnet/helm/v<version>/bin/helm.
#
# `go install helm.sh/helm/v3/cmd/helm@vX` works (helm's go.mod has no `replace`
# directives), so no wrapper module is needed. The version is stamped with
# -ldflags like upstream's Makefile does: without it `helm version` reports only
# the minor ("v3.19") and the warm check below could not tell patch releases apart.
#
# It also stamps the Kubernetes version `helm template` and `helm lint` assume when
# they have no cluster (.Capabilities.KubeVersion): upstream sets it from the
# k8s.io/client-go version in helm's go.mod; unset, it is v1.20 and a chart with
# `kubeVersion: >=1.30` cannot be templated. The warm check reads a stamp written
# after a successful build (helm version, kube version), so an old build is redone.
#
# Idempotent: a warm run checks that the binary reports the pinned version and exits.
# GOMODCACHE/GOCACHE stay in their default locations so rebuilds are incremental.
set -euo pipefail

HELM_VERSION="${ARMNET_HELM_VERSION:-3.19.5}"
base="${ARMNET_HELM_DIR:-$HOME/.cache/armnet/helm}"
bin="$base/v$HELM_VERSION/bin"
log() { echo "[setup/helm] $*"; }

have_helm() {
  [ -x "$bin/helm" ] && [ -f "$bin/helm.stamp" ] || return 1
  [[ "$(cat "$bin/helm.stamp")" == "v$HELM_VERSION "* ]] || return 1
  local out  # captured first: `| grep -q` would SIGPIPE the binary and trip pipefail
  out=$("$bin/helm" version --short 2>/dev/null) || return 1
  [[ "$out" == "v$HELM_VERSION"* ]]
}

if have_helm; then
  log "helm v$HELM_VERSION cached in $bin"
else
  command -v go >/dev/null || { log "the 'go' tool is missing: install Go >= 1.24 (https://go.dev/doc/install) and re-run scripts/setup.sh" >&2; exit 1; }
  mkdir -p "$bin"
  started=$SECONDS
  log "building helm v$HELM_VERSION with go install (cold: 3-8 min on 2 cores)"
  gomod=$(go mod download -json "helm.sh/helm/v3@v$HELM_VERSION" \
    | python3 -c 'import json,sys; print(json.load(sys.stdin)["GoMod"])')
  # k8s.io/client-go v0.34.2 -> Kubernetes 1.34
  kube_minor=$(sed -n 's|^[[:space:]]*k8s\.io/client-go v0\.\([0-9]*\)\..*|\1|p' "$gomod" | head -1)
  [ -n "$kube_minor" ] || { log "could not read the k8s.io/client-go version from $gomod"; exit 1; }
  pkg=helm.sh/helm/v3/internal/version
  ldf="-s -w -X $pkg.version=v$HELM_VERSION -X $pkg.gitTreeState=clean"
  for p in helm.sh/helm/v3/pkg/chartutil helm.sh/helm/v3/pkg/lint/rules; do
    ldf="$ldf -X $p.k8sVersionMajor=1 -X $p.k8sVersionMinor=$kube_minor"
  done
  rm -f "$bin/helm.stamp"
  # GOBIN installs straight into the cache.
  CGO_ENABLED=0 GOBIN="$bin" nice -n 10 go install -trimpath -ldflags "$ldf" \
    "helm.sh/helm/v3/cmd/helm@v$HELM_VERSION"
  echo "v$HELM_VERSION kube 1.$kube_minor" > "$bin/helm.stamp"
  have_helm || { log "helm does not report v$HELM_VERSION: $("$bin/helm" version --short 2>&1 || true)"; exit 1; }
  log "built helm in $((SECONDS - started)) s"
fi
echo "$HELM_VERSION" > "$base/current"
log "ready: $("$bin/helm" version --short) at $bin/helm"
