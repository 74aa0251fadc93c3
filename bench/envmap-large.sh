#!/usr/bin/env bash
# envmap-balls under full-size 4096 x 2048 skies (bench/make_big_sky.py: a cloudy one and one
# with a sun) and under the bundled 64 x 32 one, against Mitsuba 3, measured point by point in
# one run
# (docs/benchmarks/envmap-large-mitsuba.{md,csv,svg}). The bundled 64 x 32 sky stays in cache;
# a user's HDRI does not, and this measures what that costs each renderer.
#
# The two models agree on this scene (scenes/envmap-balls.toml's Mitsuba reference check), but
# each renderer is measured against its own converged reference, rendered at --reference-spp
# (cached in target/bench-cache), as in bench/materials-showcase.sh.
# Usage: bench/envmap-large.sh [--max-spp N] [--seeds K] [--reference-spp R]
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=256
seeds=2
reference_spp=2048
. bench/peer-env.sh
need_mitsuba envmap-large
dir=target/bench-cache/big-sky
[ -s "$dir/sun.exr" ] && [ -s "$dir/cloudy.exr" ] || target/bench-venv/bin/python bench/make_big_sky.py
# The bundled 64 x 32 sky's scene too, in the same run, for what the map's size costs each.
small=target/bench-cache/mitsuba-envmap-balls-$reference_spp.exr
mitsuba_reference envmap-balls "$reference_spp" "$small"
scenes=(--scene scenes/envmap-balls.toml) refs=("--reference envmap-balls=$small")
for sky in cloudy sun; do
    name=envmap-balls-4k-$sky
    ref=target/bench-cache/mitsuba-$name-$reference_spp.exr
    mitsuba_reference "$name" "$reference_spp" "$ref"
    scenes+=(--scene "$dir/$name.toml")
    refs+=(--reference "$name=$ref")
done
target/release/tessera bench "${scenes[@]}" --max-spp "$max_spp" --seeds "$seeds" \
    --reference-spp "$reference_spp" --name envmap-large-mitsuba \
    --peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve --variants llvm_ad_rgb \
${refs[*]} --max-spp $max_spp"
