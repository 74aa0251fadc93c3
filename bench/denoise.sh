#!/usr/bin/env bash
# Denoised against raw renders, and Mitsuba 3's raw curve, in one run (#82): `tessera bench
# --denoise` on the Cornell box, the material showcase and gltf-metals, with Mitsuba 3
# (`llvm_ad_rgb`) measured point by point as the peer. Each renderer is measured against its own
# converged reference where the models differ (tessera's by `tessera bench` at --reference-spp,
# Mitsuba's by mitsuba_peer.py at the same spp, cached in target/bench-cache); the Cornell box
# against the independent Mitsuba reference in tests/data, for both. Reports relMSE and FLIP
# (docs/benchmarks/NAME.{md,csv,svg}).
# Usage: bench/denoise.sh [--max-spp N] [--seeds K] [--reference-spp R]
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=1024
seeds=1
reference_spp=4096
. bench/peer-env.sh
need_mitsuba bench/denoise.sh
scripts/install-oidn.sh >/dev/null
refs=()
for scene in materials gltf-metals; do
    ref=target/bench-cache/mitsuba-$scene-256-$reference_spp.exr
    mitsuba_reference "$scene" "$reference_spp" "$ref"
    refs+=(--reference "$scene=$ref")
done
target/release/tessera bench --denoise --scene scenes/cornell-box.toml --scene scenes/materials.toml \
    --scene scenes/gltf-metals.toml --max-spp "$max_spp" --seeds "$seeds" \
    --reference-spp "$reference_spp" --name "denoise-$(date -u +%Y-%m-%d)" \
    --peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve --variants llvm_ad_rgb \
--reference cornell-box=tests/data/cornell-box-reference.exr ${refs[*]} --max-spp $max_spp"
