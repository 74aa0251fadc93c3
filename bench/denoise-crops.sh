#!/usr/bin/env bash
# Where denoising loses detail (#82): crops of the material showcase's textures and the caustic
# scene's caustic, each as reference | raw 16 spp | denoised 16 spp | raw 512 spp, written to
# docs/benchmarks/NAME.png with a table of each crop's relMSE in NAME.md. The references are
# tessera's own at --reference-spp (default 4096), cached in target/bench-cache.
# Usage: bench/denoise-crops.sh [--name NAME] [--reference-spp R]
set -euo pipefail
cd "$(dirname "$0")/.."
name=denoise-crops-$(date -u +%Y-%m-%d)
reference_spp=4096
while [ $# -gt 0 ]; do
    case $1 in
        --name) name=$2; shift 2 ;;
        --reference-spp) reference_spp=$2; shift 2 ;;
        *) echo "unknown argument $1" >&2; exit 2 ;;
    esac
done
scripts/install-oidn.sh >/dev/null
cargo build --release -q --workspace
T=target/release/tessera
venv=target/bench-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -c 'import numpy, OpenEXR, PIL' 2>/dev/null || "$venv/bin/pip" install --quiet numpy OpenEXR pillow
dir=target/bench-cache/denoise-crops
mkdir -p "$dir"
crops=()
# name of the scene, then its crops as LABEL=X,Y,W,H.
for spec in "materials textures=96,72,64,64 reflections=16,190,64,48" "caustic caustic=96,104,64,40"; do
    read -r scene boxes <<<"$spec"
    ref=$dir/$scene-$reference_spp.exr
    [ -s "$ref" ] || "$T" render "scenes/$scene.toml" --spp "$reference_spp" --seed 100000 --output "$ref" >/dev/null
    "$T" render "scenes/$scene.toml" --spp 16 --denoise --output "$dir/$scene-16.exr" >/dev/null
    "$T" render "scenes/$scene.toml" --spp 512 --output "$dir/$scene-512.exr" >/dev/null
    for box in $boxes; do
        crops+=("$scene ${box%%=*}:$ref:$dir/$scene-16.exr:$dir/$scene-512.exr:${box#*=}")
    done
done
out=docs/benchmarks/$name
# Before the report is opened for writing, which would itself count as a change.
dirty=$(git diff --quiet HEAD || echo ' plus uncommitted changes')
{
    echo "# Where denoising loses detail ($(date -u +%Y-%m-%d))"
    echo
    echo "Made by \`bench/denoise-crops.sh --name $name --reference-spp $reference_spp\` at commit"
    echo "$(git rev-parse --short HEAD)$dirty on: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores."
    echo
    echo "Each row of [$name.png]($name.png) is one crop, enlarged 3×: tessera's reference"
    echo "($reference_spp spp) | the raw render at 16 spp | the same render denoised (Open Image Denoise,"
    echo "\`high\`, with its albedo and normal) | the raw render at 512 spp. relMSE of each against the"
    echo "reference over the crop:"
    echo
    "$venv/bin/python" bench/denoise_crops.py "$out.png" "${crops[@]}"
} >"$out.md"
echo "wrote $out.md and $out.png"
