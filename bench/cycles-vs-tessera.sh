#!/usr/bin/env bash
# tessera against Blender's Cycles on scenes built in Blender (#83), measured in one run:
#   1. bench/blender_scenes.py builds three scenes in Blender (PyPI's bpy, in
#      target/blender-venv as tests/blender/run.sh sets it up) and exports each with the
#      tessera add-on's exporter, into target/bench-cache/blender;
#   2. each renderer's converged reference at --reference-spp (Cycles' by
#      bench/cycles_peer.py, tessera's by tessera render), cached there by spp and by a hash
#      of the scripts that make the scenes;
#   3. `tessera bench` renders the exports at 4 … --max-spp and asks Cycles
#      (bench/cycles_peer.py --serve) for each point right after measuring its own, each
#      renderer's relMSE against its own reference, and writes docs/benchmarks/NAME.{md,csv,svg};
#   4. the two references' region means, tessera's over Cycles', appended to NAME.md.
# Usage: bench/cycles-vs-tessera.sh [--max-spp N] [--seeds K] [--reference-spp R] [--name NAME]
#        [--out DIR]   (the report's folder, default docs/benchmarks)
set -euo pipefail
cd "$(dirname "$0")/.."
max_spp=1024
seeds=2
reference_spp=4096
name=cycles-$(date -u +%Y-%m-%d)
outdir=docs/benchmarks
while [ $# -gt 0 ]; do
    case $1 in
        --max-spp) max_spp=$2; shift 2 ;;
        --seeds) seeds=$2; shift 2 ;;
        --reference-spp) reference_spp=$2; shift 2 ;;
        --name) name=$2; shift 2 ;;
        --out) outdir=$2; shift 2 ;;
        *) echo "unknown argument $1" >&2; exit 2 ;;
    esac
done
venv=target/blender-venv
tests/blender/bpy-venv.sh
cargo build --release -q --workspace --features tessera-cli/bench
T=target/release/tessera
dir=target/bench-cache/blender
mkdir -p "$dir"
"$venv/bin/python" bench/blender_scenes.py -- "$dir" >"$dir.log" 2>&1 || { cat "$dir.log" >&2; exit 1; }
scenes=(blender-interior blender-metals-glass blender-textured)
# References are cached by what makes the scenes (a .blend file is not byte-reproducible).
key=$(cat bench/blender_scenes.py tests/blender/units.py blender/tessera/export.py | sha256sum | cut -c1-12)
args=()
refs=()
for s in "${scenes[@]}"; do
    cycles_ref=$dir/$s-$key-cycles-$reference_spp.exr
    tessera_ref=$dir/$s-$key-tessera-$reference_spp.exr
    [ -s "$cycles_ref" ] || "$venv/bin/python" bench/cycles_peer.py --scenes "$dir" \
        --make-reference "$s=$cycles_ref" --reference-spp "$reference_spp"
    [ -s "$tessera_ref" ] || "$T" render "$dir/$s/$s.toml" --spp "$reference_spp" --seed 100000 \
        --output "$tessera_ref" >/dev/null
    args+=(--scene "$dir/$s/$s.toml" --reference "$s=$tessera_ref")
    refs+=(--reference "$s=$cycles_ref")
done
mkdir -p "$outdir"
"$T" bench "${args[@]}" --max-spp "$max_spp" --seeds "$seeds" --name "$name" --out "$outdir" \
    --peer-command "$venv/bin/python bench/cycles_peer.py --scenes $dir --serve ${refs[*]}"
dirty=$(git diff --quiet HEAD || echo " plus uncommitted changes")
blender=$("$venv/bin/python" -c 'import bpy; print(bpy.app.version_string)' 2>/dev/null | tail -1)
python3 - "$outdir/$name.md" <<PY
import sys
path = sys.argv[1]
lines = open(path).read().split("\n")
lines[2:2] = ["Run by \`bench/cycles-vs-tessera.sh --max-spp $max_spp --seeds $seeds --reference-spp $reference_spp\` "
              "at commit $(git rev-parse --short HEAD)$dirty: tessera against Blender $blender's Cycles (CPU, path "
              "tracing, no denoising, no adaptive sampling, no clamping, bounces up to 64) on three scenes built in "
              "Blender by \`bench/blender_scenes.py\` and exported by the tessera add-on's exporter "
              "([blender.md](../blender.md)); each renderer's relMSE is against its own converged reference.", ""]
open(path, "w").write("\n".join(lines))
PY
{
    echo
    echo "## The converged images, region by region"
    echo
    echo "Each renderer's reference ($reference_spp spp), tessera's mean over Cycles' in 4×4 blocks"
    echo "of the film, top row first (\`bench/region_means.py\`)."
    echo
    for s in "${scenes[@]}"; do
        "$venv/bin/python" bench/region_means.py -- "$s" "$dir/$s-$key-cycles-$reference_spp.exr" \
            "$dir/$s-$key-tessera-$reference_spp.exr" 2>/dev/null | grep -v "^Read\|^Info"
    done
} >>"$outdir/$name.md"
echo "wrote $outdir/$name.md"
