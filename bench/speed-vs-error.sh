#!/usr/bin/env bash
# Speed against error, tessera and its peers measured in one run on this machine:
#   1. Mitsuba 3 (PyPI `mitsuba`) renders the Cornell box, variants llvm_ad_rgb and scalar_rgb,
#      when Python 3 is here (it is installed into target/bench-venv; llvm_ad_rgb needs
#      Debian's libllvm19, which this script installs with apt-get when it can);
#   2. `tessera bench` renders cornell-box, spheres and glass-mirror and writes
#      docs/benchmarks/speed-vs-error.{md,csv,svg} with the peers' rows and the ratios.
# Usage: bench/speed-vs-error.sh [--max-spp N] [--seeds K] [--reference-spp R]
# (R: spp of the references tessera renders for scenes without an independent one)
set -euo pipefail
cd "$(dirname "$0")/.."

max_spp=4096
seeds=2
reference_spp=8192
while [ $# -gt 0 ]; do
    case "$1" in
        --max-spp) max_spp="$2"; shift 2 ;;
        --seeds) seeds="$2"; shift 2 ;;
        --reference-spp) reference_spp="$2"; shift 2 ;;
        *) echo "unknown argument: $1" >&2; exit 2 ;;
    esac
done

cargo build --release -p tessera-cli
mkdir -p target/bench
peers=()
if command -v python3 >/dev/null; then
    if [ ! -x target/bench-venv/bin/python ]; then
        python3 -m venv target/bench-venv
        target/bench-venv/bin/pip install --quiet mitsuba numpy
    fi
    llvm=$(ls /usr/lib/*/libLLVM.so.19.1 2>/dev/null | head -1 || true)
    if [ -z "$llvm" ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q libllvm19 >/dev/null || true
        llvm=$(ls /usr/lib/*/libLLVM.so.19.1 2>/dev/null | head -1 || true)
    fi
    [ -n "$llvm" ] && export DRJIT_LIBLLVM_PATH="$llvm"
    [ -z "$llvm" ] && echo "no libLLVM.so.19.1: mitsuba's llvm_ad_rgb variant will be skipped" >&2
    target/bench-venv/bin/python bench/mitsuba_peer.py \
        --reference tests/data/cornell-box-reference.exr --out target/bench/mitsuba.csv \
        --max-spp "$max_spp" --seeds "$seeds"
    peers+=(--peer target/bench/mitsuba.csv)
else
    echo "no python3: reporting tessera alone" >&2
fi
target/release/tessera bench --max-spp "$max_spp" --seeds "$seeds" --reference-spp "$reference_spp" "${peers[@]}"
