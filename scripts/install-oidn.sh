#!/usr/bin/env bash
# Installs Intel Open Image Denoise 2.5.1, which `tessera render --denoise` loads at run time,
# into target/oidn/lib (or DEST/lib): Intel's official Linux x86-64 build as PyPI's pyoidn
# wheel carries it (the library, its core, its CPU device and TBB; no GPU devices). The wheel
# is pinned by version and SHA-256. Runs in seconds once done; safe to run concurrently.
#
#   scripts/install-oidn.sh [DEST]
set -euo pipefail
cd "$(dirname "$0")/.."
dest=${1:-target/oidn}
version=2.5.1.0
sha256=32ad13368f8de1ef63001942ad05b02a00cd732d1206d97f352d3a3f606d823e
files=(libOpenImageDenoise.so.2 libOpenImageDenoise_core.so.2.5.1
       libOpenImageDenoise_device_cpu.so.2.5.1 libtbb.so.12)

installed() { [[ -f $dest/lib/.installed && $(cat "$dest/lib/.installed") == "$version" ]]; }
installed && exit 0
mkdir -p "$dest"
exec 9>"$dest/.lock"
flock 9
installed && exit 0

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "install-oidn: fetching pyoidn $version from PyPI" >&2
python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
  --platform manylinux2014_x86_64 --python-version 3.11 "pyoidn==$version" -d "$tmp"
wheel=("$tmp"/pyoidn-*.whl)
echo "$sha256  ${wheel[0]}" | sha256sum --check --quiet
python3 - "${wheel[0]}" "$tmp/lib" "${files[@]}" <<'PY'
import os, sys, zipfile
wheel, out, names = sys.argv[1], sys.argv[2], sys.argv[3:]
os.makedirs(out)
with zipfile.ZipFile(wheel) as z:
    for n in names:
        with z.open("pyoidn/oidn/lib/" + n) as src, open(os.path.join(out, n), "wb") as dst:
            dst.write(src.read())
        os.chmod(os.path.join(out, n), 0o755)
PY
echo "$version" >"$tmp/lib/.installed"
rm -rf "$dest/lib"
mv "$tmp/lib" "$dest/lib"
echo "install-oidn: Open Image Denoise $version in $dest/lib" >&2
