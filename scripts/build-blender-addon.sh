#!/usr/bin/env bash
# Packs the Blender add-on (blender/tessera, a Blender 4.2+ extension) into one zip that
# Blender installs: Edit > Preferences > Get Extensions > (menu) Install from Disk.
#
#   scripts/build-blender-addon.sh [OUT.zip]     (default target/tessera-blender.zip)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/tessera-blender.zip}
mkdir -p "$(dirname "$out")"
python3 - "$out" <<'PY'
import pathlib, sys, zipfile
src = pathlib.Path("blender/tessera")
with zipfile.ZipFile(sys.argv[1], "w", zipfile.ZIP_DEFLATED) as z:
    for f in sorted(src.rglob("*")):
        if f.is_file() and "__pycache__" not in f.parts:
            z.write(f, f.relative_to(src))
PY
echo "wrote $out"
