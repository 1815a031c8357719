#!/usr/bin/env bash
# The pod sandbox ("pause") image for the test-bed node, built here because no
# registry is reachable: a static C program that sleeps until SIGTERM/SIGINT and
# reaps children, in a `scratch` image made with buildah, stored in Podman's
# storage (buildah and podman share it) as
#   localhost/armnet-pause:<recipe hash>   and tagged localhost/armnet-pause:testbed.
# The test bed imports it into its containerd and names it as `sandbox_image`.
# Like 40-base-image.sh the hash covers the recipe (source + build flags), so a
# warm run only checks the image exists.
set -euo pipefail
log() { echo "[setup/pause-image] $*"; }

read -r -d '' source <<'EOF' || true
/* armnet test-bed pause: the process that holds a pod's namespaces. */
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

static void stop(int sig) { (void)sig; _exit(0); }

static void reap(int sig) {
  (void)sig;
  while (waitpid(-1, NULL, WNOHANG) > 0) {
  }
}

int main(void) {
  struct sigaction sa = {0};
  sa.sa_handler = stop;
  sigaction(SIGTERM, &sa, NULL);
  sigaction(SIGINT, &sa, NULL);
  sa.sa_handler = reap;
  sa.sa_flags = SA_NOCLDSTOP | SA_RESTART;
  sigaction(SIGCHLD, &sa, NULL);
  for (;;) pause();
  return 0;
}
EOF
cflags="-Os -static -s"
recipe="armnet-pause v1; gcc $cflags; scratch; entrypoint /pause; user 65535:65535; $source"
hash=$(printf '%s' "$recipe" | sha256sum | cut -c1-12)
repo=localhost/armnet-pause
tag="$repo:$hash"

for tool in podman buildah gcc; do
  command -v "$tool" >/dev/null || { log "$tool is missing: run scripts/setup.sh (step 20-system installs it)" >&2; exit 1; }
done

if podman image exists "$tag"; then
  log "cached: $tag"
else
  started=$SECONDS
  work=$(mktemp -d /var/tmp/armnet-pause.XXXXXX)
  ctr=""
  trap 'rm -rf "$work"; [ -z "$ctr" ] || buildah rm "$ctr" >/dev/null 2>&1 || true' EXIT
  printf '%s\n' "$source" > "$work/pause.c"
  # shellcheck disable=SC2086 # cflags is a word list
  gcc $cflags -o "$work/pause" "$work/pause.c"
  ctr=$(buildah from scratch)
  buildah copy --quiet --chmod 0755 "$ctr" "$work/pause" /pause >/dev/null
  buildah config --entrypoint '["/pause"]' --user 65535:65535 \
    --label "org.armnet.recipe=$hash" "$ctr"
  buildah commit --quiet "$ctr" "$tag" >/dev/null
  log "built $tag ($(stat -c %s "$work/pause") bytes) in $((SECONDS - started)) s"
fi

podman tag "$tag" "$repo:testbed"
log "ready: $repo:testbed -> $tag"
