#!/usr/bin/env bash
# tessera's glTF light and emission units, its reading of a Blender camera's framing, the
# Blender add-on's area lights and world map, and
# its pbr material against Principled BSDFs (a default material, a rough blue, a rough gold
# metal), against Cycles (#83): Blender as a Python module
# (PyPI's bpy 4.5, Python 3.11) builds small scenes, exports them with its own glTF exporter
# and renders them with Cycles; tessera renders each export; every region's mean must agree
# within 2% (tests/blender/compare.py). Sets up target/blender-venv on first use (a download
# of about 400 MB). Run from anywhere: `tests/blender/run.sh`.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/blender-venv
tests/blender/bpy-venv.sh
cargo build --release --workspace -q
out=target/blender-units
rm -rf "$out"
"$venv/bin/python" tests/blender/units.py -- "$out" >"$out.log" 2>&1 || { cat "$out.log" >&2; exit 1; }
status=0
for size in "$out"/*.size; do
    name=$(basename "$size" .size)
    # The add-on's export (a TOML scene placing the glTF file) where units.py made one.
    scene=$out/$name.glb
    [ -f "$out/$name.0001.toml" ] && scene=$out/$name.0001.toml
    target/release/tessera render "$scene" --spp 256 --resolution "$(cat "$out/$name.size")" \
        --output "$out/$name-tessera.exr" >/dev/null
    echo "$name:"
    "$venv/bin/python" tests/blender/compare.py -- "$out/$name-cycles.exr" "$out/$name-tessera.exr" 2>/dev/null | grep -E "region|off by" || status=1
    "$venv/bin/python" tests/blender/compare.py -- "$out/$name-cycles.exr" "$out/$name-tessera.exr" >/dev/null 2>&1 || status=1
done
exit $status
