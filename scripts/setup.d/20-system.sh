#!/usr/bin/env bash
# System packages for the test bed: the container engine (Podman + runc, no crun:
# crun refuses this machine's hybrid cgroups), debootstrap for the base image,
# NATS with JetStream, openssl; for the test-bed node (docs/reference/testbed-host.md):
# containerd, the CNI plugins (in /usr/lib/cni), and gcc + buildah to build the
# pause image (step 45); Chromium and its WebDriver for the FMS page's browser tests
# (tests/browser/, driven with selenium); zsh, so the `armnet completion zsh` test runs the
# generated script in real zsh instead of skipping. `apt-get update` runs once and only when something
# is missing, so a warm run never touches the network.
#
# Also writes /etc/containers/containers.conf (runc + ulimits below the VM's hard
# limits) when it is absent; see docs/reference/testbed-host.md, "Podman", for why.
set -euo pipefail
log() { echo "[setup/system] $*"; }

packages=(podman runc debootstrap nats-server openssl ca-certificates
          containerd containernetworking-plugins buildah gcc libc6-dev chromium chromium-driver zsh)

missing=()
for p in "${packages[@]}"; do
  [ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null)" = "install ok installed" ] || missing+=("$p")
done

if [ "$(id -u)" -ne 0 ] && [ "${#missing[@]}" -gt 0 ]; then
  log "missing packages: ${missing[*]}; re-run as root (sudo scripts/setup.sh)" >&2
  exit 1
fi

if [ "${#missing[@]}" -gt 0 ]; then
  log "installing: ${missing[*]}"
  apt_get=(apt-get -o DPkg::Lock::Timeout=600 -q -y)
  export DEBIAN_FRONTEND=noninteractive
  "${apt_get[@]}" update
  avail=()
  for p in "${missing[@]}"; do
    if apt-cache show "$p" >/dev/null 2>&1; then avail+=("$p")
    else log "package $p is not in the configured apt sources" >&2; exit 1
    fi
  done
  [ "${#avail[@]}" -eq 0 ] || "${apt_get[@]}" install "${avail[@]}"
else
  log "packages present: ${packages[*]}"
fi

conf=/etc/containers/containers.conf
if [ ! -f "$conf" ] || ! grep -q 'runtime *= *"runc"' "$conf"; then
  if [ -f "$conf" ] && grep -Eq '^\s*\[(containers|engine)\]' "$conf"; then
    log "$conf exists with its own [containers]/[engine] tables; set runtime = \"runc\" and" \
        "default_ulimits = [\"nofile=4096:16384\", \"nproc=4096:32768\"] in it by hand" >&2
    exit 1
  fi
  log "writing runc + ulimit defaults to $conf"
  mkdir -p /etc/containers
  cat >> "$conf" <<'EOF'
# Written by armnet scripts/setup.d/20-system.sh.
# runc, not crun: crun refuses hybrid cgroup v1/v2 hosts. The ulimits stay below the
# VM's hard limits (nofile 20000) because runc cannot raise them without
# CAP_SYS_RESOURCE. The Docker-compatible API ignores default_ulimits: pass them per
# container (testbed/armnet_testbed does).
[containers]
default_ulimits = ["nofile=4096:16384", "nproc=4096:32768"]

[engine]
runtime = "runc"
EOF
else
  log "$conf already selects runc"
fi

podman --version
runc --version | head -1
nats-server --version
containerd --version
zsh --version
