#!/usr/bin/env bash
# `tessera render`'s speed under mimalloc (the default build) against the system's malloc
# (`--no-default-features`), alternating runs of the two builds in one session: one thread and
# every core, medians. The renderer allocates little per sample, so the two should be within
# noise; this checks that the allocator the coordinator needs does not tax local renders.
#
#   bench/allocator-ab.sh [SCENE] [SPP] [RUNS] [MIMALLOC_BINARY SYSTEM_BINARY]
#
# Without the two binaries it builds them (target/release and target/system-alloc). Markdown
# on stdout.
set -euo pipefail
cd "$(dirname "$0")/.."
SCENE=${1:-scenes/cornell-box.toml}
SPP=${2:-64}
RUNS=${3:-5}
if [ $# -ge 5 ]; then A=$(realpath "$4"); B=$(realpath "$5"); else
  cargo build --release -q -p tessera-cli
  CARGO_TARGET_DIR=target/system-alloc cargo build --release -q -p tessera-cli --no-default-features
  A=$PWD/target/release/tessera; B=$PWD/target/system-alloc/release/tessera
fi
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
rate() { sed -n 's/.* \([0-9.]*\) Msamples\/s.*/\1/p'; }
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR] = $1} END {print a[int((NR + 1) / 2)]}'; }
echo "Machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores. \`$SCENE\` at $SPP spp, $RUNS alternating runs each; medians (Msamples/s)."
echo
echo "| threads | mimalloc | system malloc | mimalloc / system |"
echo "|---:|---:|---:|---:|"
for threads in 1 "$(nproc)"; do
  a=(); b=()
  for _ in $(seq "$RUNS"); do
    a+=("$("$A" render "$SCENE" --spp "$SPP" --threads "$threads" --output "$WORK/a.exr" | rate)")
    b+=("$("$B" render "$SCENE" --spp "$SPP" --threads "$threads" --output "$WORK/b.exr" | rate)")
    cmp -s "$WORK/a.exr" "$WORK/b.exr" || { echo "the two builds' EXRs differ" >&2; exit 1; }
  done
  ma=$(median "${a[@]}"); mb=$(median "${b[@]}")
  awk -v t="$threads" -v a="$ma" -v b="$mb" 'BEGIN {printf "| %d | %.2f | %.2f | %.3f |\n", t, a, b, a / b}'
done
