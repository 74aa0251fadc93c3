#!/usr/bin/env bash
# The mesh benchmark: tessera against Mitsuba 3 (llvm_ad_rgb, from PyPI) on a scene of
# 1,048,576 triangles (bench/make_million.py: the Cornell box's walls and light around a bumpy
# sphere), measured point by point in the same run as speed-vs-error.sh does, relMSE against
# an independent Mitsuba reference; plus each mesh's BVH build time. The same scene with an
# analytic sphere in the mesh's place is measured alongside, so that what the mesh costs each
# renderer per sample is the difference of the two scenes' times. Writes
# docs/benchmarks/mesh-speed-vs-error.{md,csv,svg}.
#
#   bench/mesh-speed.sh [--max-spp N] [--seeds K] [--reference-spp N]
set -euo pipefail
cd "$(dirname "$0")/.."
max_spp=256
seeds=2
reference_spp=4096
. bench/peer-env.sh
need_mitsuba mesh-speed
dir=target/bench-cache/mesh-million
[ -s "$dir/bumpy-sphere.ply" ] && [ -s "$dir/mesh-million-emissive.toml" ] ||
    target/bench-venv/bin/python bench/make_million.py "$dir"
scene_args=()
refs=()
for name in mesh-million mesh-million-analytic; do
    ref=target/bench-cache/mitsuba-$name-$reference_spp.exr
    mitsuba_reference "$name" "$reference_spp" "$ref"
    scene_args+=(--scene "$dir/$name.toml" --reference "$name=$ref")
    refs+=("--reference $name=$ref")
done
target/release/tessera bench "${scene_args[@]}" --max-spp "$max_spp" --seeds "$seeds" \
    --name mesh-speed-vs-error \
    --peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve --variants llvm_ad_rgb \
${refs[*]} --max-spp $max_spp"
