#!/usr/bin/env bash
# The material showcase (scenes/materials.toml: glTF `pbr` materials with textures and normal
# maps, rough gold, frosted glass and plastic under an HDR sky) against Mitsuba 3, measured
# point by point in one run (docs/benchmarks/materials-showcase.{md,csv,svg}).
#
# The two renderers' models of the glTF material differ (Mitsuba's `principled` is Disney's,
# tessera's `pbr` is glTF's), so each is measured against its own converged reference: tessera's
# rendered by `tessera bench` at --reference-spp, Mitsuba's by mitsuba_peer.py at the same spp
# (cached in target/bench-cache). The ratio is of convergence, the same scene's error at equal
# time for each model.
# Usage: bench/materials-showcase.sh [--max-spp N] [--seeds K] [--reference-spp R]
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=256
seeds=2
reference_spp=4096
. bench/peer-env.sh
need_mitsuba materials-showcase
ref=target/bench-cache/mitsuba-materials-$reference_spp.exr
mitsuba_reference materials "$reference_spp" "$ref"
target/release/tessera bench --scene scenes/materials.toml --max-spp "$max_spp" --seeds "$seeds" \
    --reference-spp "$reference_spp" --name materials-showcase \
    --peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve --variants llvm_ad_rgb \
--reference materials=$ref --max-spp $max_spp"
