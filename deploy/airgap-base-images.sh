#!/usr/bin/env bash
# Builds, without any container registry, the two base images deploy/Dockerfile names:
#
#   debian:bookworm-slim   a minimal Debian 12 root file system made by debootstrap from
#                          Debian's package mirror, imported with `docker import`;
#   rust:1-slim-bookworm   the same plus gcc/libc6-dev/ca-certificates (also by debootstrap)
#                          and the Rust toolchain already installed on this machine.
#
# Where images can be pulled, skip this: `docker pull` gets the real ones and the same
# Dockerfile builds unchanged. Existing images are kept unless --force is given.
#
#   deploy/airgap-base-images.sh [--force]
#
# Needs: root (debootstrap), debootstrap (apt-get install debootstrap), docker, rustc/cargo.
set -euo pipefail
FORCE=${1:-}
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
SUITE=bookworm
RUNTIME_TAG=debian:bookworm-slim
BUILD_TAG=rust:1-slim-bookworm

have() { docker image inspect "$1" >/dev/null 2>&1; }
if [[ "$FORCE" != --force ]] && have "$RUNTIME_TAG" && have "$BUILD_TAG"; then
  echo "base images $RUNTIME_TAG and $BUILD_TAG exist (use --force to rebuild)"
  exit 0
fi
[[ $(id -u) == 0 ]] || { echo "debootstrap needs root" >&2; exit 1; }
if ! command -v debootstrap >/dev/null; then
  echo "== installing debootstrap from Debian's packages"
  apt-get install -y -q debootstrap >/dev/null 2>&1 \
    || { apt-get update -q >/dev/null && apt-get install -y -q debootstrap >/dev/null; } \
    || { echo "debootstrap is missing and could not be installed" >&2; exit 1; }
fi
SYSROOT=$(rustc --print sysroot)
[[ -x "$SYSROOT/bin/cargo" ]] || { echo "no cargo next to rustc in $SYSROOT" >&2; exit 1; }

WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

echo "== $RUNTIME_TAG: debootstrap --variant=minbase $SUITE"
debootstrap --variant=minbase "$SUITE" "$WORK/runtime" "$MIRROR" >"$WORK/runtime.log" 2>&1 \
  || { tail -20 "$WORK/runtime.log" >&2; exit 1; }
# Slim it the way the official image is slimmed: no docs, man pages or apt lists.
rm -rf "$WORK/runtime"/usr/share/{doc,man,info}/* "$WORK/runtime"/var/lib/apt/lists/* \
  "$WORK/runtime"/var/cache/apt/archives/*.deb
tar -C "$WORK/runtime" -c . | docker import \
  --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  --change 'CMD ["bash"]' - "$RUNTIME_TAG"

echo "== $BUILD_TAG: debootstrap with gcc, and the Rust toolchain of this machine ($(rustc --version))"
debootstrap --variant=minbase --include=gcc,libc6-dev,ca-certificates "$SUITE" "$WORK/build" "$MIRROR" \
  >"$WORK/build.log" 2>&1 || { tail -20 "$WORK/build.log" >&2; exit 1; }
rm -rf "$WORK/build"/usr/share/{doc,man,info}/* "$WORK/build"/var/lib/apt/lists/*
# The build stage downloads crates: trust what this machine trusts besides Debian's CAs (for
# example a TLS-inspecting proxy's CA in /usr/local/share/ca-certificates).
for ca in /usr/local/share/ca-certificates/*.crt; do
  [[ -f "$ca" ]] || continue
  cp "$ca" "$WORK/build/usr/local/share/ca-certificates/"
  cat "$ca" >>"$WORK/build/etc/ssl/certs/ca-certificates.crt"
done
mkdir -p "$WORK/build/usr/local/rust" "$WORK/build/usr/local/cargo"
cp -a "$SYSROOT/bin" "$SYSROOT/lib" "$WORK/build/usr/local/rust/"
tar -C "$WORK/build" -c . | docker import \
  --change 'ENV PATH=/usr/local/cargo/bin:/usr/local/rust/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  --change 'ENV CARGO_HOME=/usr/local/cargo' \
  --change 'CMD ["bash"]' - "$BUILD_TAG"
docker image ls --filter reference="$RUNTIME_TAG" --filter reference="$BUILD_TAG"
