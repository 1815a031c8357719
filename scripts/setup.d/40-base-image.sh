#!/usr/bin/env bash
# The container base image, built without any registry: a debootstrap'd Debian
# bookworm (minbase + python3 + python3-venv), imported into Podman as
#   localhost/armnet-base:bookworm-<recipe hash>   and tagged localhost/armnet-base:bookworm.
# The hash covers the recipe below (not the mirror), so a warm run finds the image
# and does nothing; changing the recipe builds a new, differently tagged image.
# The mirror is read from the machine's apt sources at run time (never hard-coded).
set -euo pipefail
log() { echo "[setup/base-image] $*"; }

suite=bookworm
variant=minbase
include=python3,python3-venv,python3-pip,ca-certificates
recipe="armnet-base v1; debootstrap --variant=$variant --include=$include $suite; apt clean; ENV LANG=C.UTF-8 PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin; CMD /bin/bash"
hash=$(printf '%s' "$recipe" | sha256sum | cut -c1-12)
repo=localhost/armnet-base
tag="$repo:$suite-$hash"

for tool in podman debootstrap; do
  command -v "$tool" >/dev/null || { log "$tool is missing: run scripts/setup.sh (step 20-system installs it)" >&2; exit 1; }
done

if podman image exists "$tag"; then
  log "cached: $tag"
else
  mirror=""
  if [ -f /etc/apt/sources.list.d/debian.sources ]; then
    # First deb822 stanza whose Suites has exactly "$suite" (skips bookworm-security).
    mirror=$(awk -v s="$suite" '
      /^[[:space:]]*$/ { if (hit && uri != "") { print uri; exit } hit=0; uri=""; next }
      /^URIs:/ { uri=$2 }
      /^Suites:/ { for (i = 2; i <= NF; i++) if ($i == s) hit=1 }
      END { if (hit && uri != "") print uri }' /etc/apt/sources.list.d/debian.sources | head -1)
  fi
  if [ -z "$mirror" ] && [ -f /etc/apt/sources.list ]; then
    mirror=$(awk -v s="$suite" '$1 == "deb" && $3 == s { print $2; exit }' /etc/apt/sources.list)
  fi
  [ -n "$mirror" ] || { log "no Debian $suite mirror found in /etc/apt/sources.list.d/debian.sources or /etc/apt/sources.list" >&2; exit 1; }

  started=$SECONDS
  work=$(mktemp -d /var/tmp/armnet-base.XXXXXX)
  trap 'rm -rf "$work"' EXIT
  log "debootstrap $suite ($variant + $include) from the configured apt mirror (cold: ~1-2 min)"
  nice -n 10 debootstrap --variant="$variant" --include="$include" "$suite" "$work/rootfs" "$mirror" \
    > "$work/debootstrap.log" 2>&1 || { tail -30 "$work/debootstrap.log" >&2; log "debootstrap failed" >&2; exit 1; }
  chroot "$work/rootfs" apt-get clean
  rm -rf "$work/rootfs/var/lib/apt/lists/"* "$work/rootfs/var/cache/apt/"*.bin
  log "importing into podman as $tag"
  tar -C "$work/rootfs" -c . | podman import \
    --change 'ENV=LANG=C.UTF-8' \
    --change 'ENV=PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'CMD=["/bin/bash"]' \
    --quiet --message "$recipe" - "$tag" >/dev/null
  log "built $tag in $((SECONDS - started)) s"
fi

podman tag "$tag" "$repo:$suite"
podman run --rm --runtime runc --ulimit nofile=4096:16384 --ulimit nproc=4096:32768 --network none \
  "$repo:$suite" python3 -c 'import sys, venv; print("[setup/base-image] python", sys.version.split()[0], "ok")'
log "ready: $repo:$suite -> $tag"
