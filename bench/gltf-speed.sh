#!/usr/bin/env bash
# The glTF scenes (scenes/gltf-metals.toml: textured metals; scenes/gltf-glass.toml: volume
# glass, smooth and rough; gltf-big: bench/make_big_gltf.py's ball of 2,097,152 triangles in
# the textured metal, made here under target/bench-cache/gltf-big) against Mitsuba 3 reading
# the same files (bench/gltf_mitsuba.py), measured point by point in one run
# (docs/benchmarks/gltf-speed.{md,csv,svg}). The two models agree on these scenes
# (tests/reference.rs checks every 32² region of the first two within 0.5%), so both renderers
# are measured against one reference: Mitsuba's at --reference-spp, cached in
# target/bench-cache.
# Usage: bench/gltf-speed.sh [--max-spp N] [--seeds K] [--reference-spp R]
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=256
seeds=2
reference_spp=8192
. bench/peer-env.sh
need_mitsuba gltf-speed
refs=()
serve_refs=
big=target/bench-cache/gltf-big
[ -s "$big/big.glb" ] && [ -s "$big/gltf-big.toml" ] ||
    target/bench-venv/bin/python bench/make_big_gltf.py "$big"
for scene in gltf-metals gltf-glass gltf-big; do
    file=scenes/$scene.toml
    [ "$scene" = gltf-big ] && file=$big/gltf-big.toml
    ref=target/bench-cache/mitsuba-$scene-256-$reference_spp.exr
    mitsuba_reference "$scene" "$reference_spp" "$ref"
    refs+=(--scene "$file" --reference "$scene=$ref")
    serve_refs="$serve_refs --reference $scene=$ref"
done
target/release/tessera bench "${refs[@]}" --max-spp "$max_spp" --seeds "$seeds" --name gltf-speed \
    --peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve --variants llvm_ad_rgb \
$serve_refs --max-spp $max_spp"
