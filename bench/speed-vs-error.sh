#!/usr/bin/env bash
# Speed against error, tessera and its peers measured in one run on this machine:
#   1. Mitsuba 3 (PyPI `mitsuba`) is the peer for the Cornell box and glass-mirror, variants
#      llvm_ad_rgb and scalar_rgb, when Python 3 is here (it is installed into
#      target/bench-venv; llvm_ad_rgb needs Debian's libllvm19, which this script installs with
#      apt-get when it can). glass-mirror's reference is Mitsuba's too, rendered once at
#      16384 spp and cached in target/bench-cache (about 13 minutes on 2 cores);
#   2. `tessera bench` renders cornell-box, spheres and glass-mirror, asks Mitsuba
#      (`mitsuba_peer.py --serve`) for each point right after measuring its own, and writes
#      docs/benchmarks/speed-vs-error.{md,csv,svg} with the peers' rows and the ratios.
#      spheres (a sky gradient and an infinite plane, which Mitsuba has no exact form of) is
#      measured against tessera's own reference.
# Usage: bench/speed-vs-error.sh [--max-spp N] [--seeds K] [--reference-spp R]
# (R: spp of the references tessera renders for scenes without an independent one)
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=4096
seeds=2
reference_spp=8192
. bench/peer-env.sh
peers=()
if [ "$have_python" = 1 ]; then
    [ -z "$llvm" ] && echo "no libLLVM.so.19.1: mitsuba's llvm_ad_rgb variant will be skipped" >&2
    gm_ref=target/bench-cache/mitsuba-glass-mirror-16384.exr
    if [ ! -s "$gm_ref" ]; then
        mkdir -p target/bench-cache
        target/bench-venv/bin/python bench/mitsuba_peer.py \
            --make-reference "glass-mirror=$gm_ref.tmp.exr" --reference-spp 16384
        mv "$gm_ref.tmp.exr" "$gm_ref"
    fi
    # Measured point by point, each right after tessera's point of the same scene, spp and
    # seed, so that a slow minute of a shared machine falls on both renderers.
    peers+=(--peer-command "target/bench-venv/bin/python bench/mitsuba_peer.py --serve \
--reference cornell-box=tests/data/cornell-box-reference.exr --reference glass-mirror=$gm_ref \
--max-spp $max_spp" --reference "glass-mirror=$gm_ref")
else
    echo "no python3: reporting tessera alone" >&2
fi
target/release/tessera bench --max-spp "$max_spp" --seeds "$seeds" --reference-spp "$reference_spp" "${peers[@]}"
