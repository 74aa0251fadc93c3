#!/usr/bin/env bash
# Multi-core and multi-worker scaling on one machine: `tessera render` of the Cornell box at
# 1, 2, 4, … threads up to every core; then the same job on a coordinator with one worker of
# every core, with two workers of half the cores each and with four of a quarter, at the unit
# rule's batch (BATCHES="16 256" for others; "rule" is the default), each checked bit for bit
# against `tessera render` and timed against it; the coordinator's CPU time and bytes written
# per Gsample are read from /proc.
#
#   bench/scaling.sh [TESSERA] [SPP] [THREADS_SPP]
#
# Markdown on stdout; the binary defaults to the build, SPP (the farm runs) to 1024 and
# THREADS_SPP (the thread sweep, whose one-thread run is the slowest) to 256.
set -euo pipefail
cd "$(dirname "$0")/.."
T=${1:-target/release/tessera}
SPP=${2:-1024}
TSPP=${3:-256}
SCENE=scenes/cornell-box.toml
CORES=$(nproc)
WORK=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$WORK"' EXIT
TICK=$(getconf CLK_TCK)
now() { date +%s.%N; }
minus() { awk -v a="$1" -v b="$2" 'BEGIN {print a - b}'; }
rate() { sed -n 's/.* \([0-9.]*\) Msamples\/s.*/\1/p'; }
SAMPLES=$((256 * 256 * SPP))

echo "Machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $CORES cores. Scene: $SCENE; the thread sweep at $TSPP spp, the farm at $SPP spp ($SAMPLES samples)."
echo
echo "| threads | Msamples/s | speed-up | per thread |"
echo "|---:|---:|---:|---:|"
one=""
n=1
while [ "$n" -le "$CORES" ]; do
  r=$("$T" render "$SCENE" --spp "$TSPP" --threads "$n" --output "$WORK/t$n.exr" | rate)
  one=${one:-$r}
  awk -v n="$n" -v r="$r" -v one="$one" 'BEGIN {printf "| %d | %.2f | %.2f× | %.0f%% |\n", n, r, r / one, 100 * r / one / n}'
  if [ "$n" -lt "$CORES" ] && [ $((n * 2)) -gt "$CORES" ]; then n=$CORES; else n=$((n * 2)); fi
done
"$T" render "$SCENE" --spp "$SPP" --threads "$CORES" --output "$WORK/local.exr" >/dev/null

farm() { # WORKERS BATCH ("rule": no --batch flag)
  local workers=$1 batch=$2 threads=$(( CORES / $1 ))
  local flag=()
  [ "$batch" = rule ] || flag=(--batch "$batch")
  rm -rf "$WORK/data"
  "$T" coordinator --listen 127.0.0.1:0 --data-dir "$WORK/data" >"$WORK/coord.out" 2>/dev/null &
  local cpid=$!
  until grep -q listening "$WORK/coord.out" 2>/dev/null; do sleep 0.05; done
  local url="http://$(sed -n 's/listening on //p' "$WORK/coord.out")"
  local pids=()
  for i in $(seq "$workers"); do
    "$T" worker --coordinator "$url" --threads "$threads" --name "w$i" 2>/dev/null &
    pids+=($!)
  done
  sleep 1
  local c0 w0 t0 t1 c1 w1
  c0=$(awk '{print $14 + $15}' "/proc/$cpid/stat"); w0=$(awk '/^write_bytes/ {print $2}' "/proc/$cpid/io")
  t0=$(now)
  "$T" submit "$SCENE" --coordinator "$url" --spp "$SPP" "${flag[@]}" --wait --output "$WORK/farm.exr" >/dev/null 2>&1
  t1=$(now)
  c1=$(awk '{print $14 + $15}' "/proc/$cpid/stat"); w1=$(awk '/^write_bytes/ {print $2}' "/proc/$cpid/io")
  kill "${pids[@]}" "$cpid" 2>/dev/null || true; wait "${pids[@]}" "$cpid" 2>/dev/null || true
  "$T" render "$SCENE" --spp "$SPP" "${flag[@]}" --threads "$CORES" --output "$WORK/local-b$batch.exr" >/dev/null
  local same=yes
  cmp -s "$WORK/farm.exr" "$WORK/local-b$batch.exr" || same=NO
  awk -v w="$workers" -v th="$threads" -v b="$batch" -v wall="$(minus "$t1" "$t0")" \
      -v cpu="$(awk -v a="$c1" -v b="$c0" -v t="$TICK" 'BEGIN {print (a - b) / t}')" -v bytes="$((w1 - w0))" -v s="$SAMPLES" -v same="$same" \
      'BEGIN {printf "| %d × %d threads | %s | %.2f | %.2f | %.3f | %.1f | %s |\n", w, th, b, wall, s / wall / 1e6, cpu * 1e9 / s, bytes / 1e6 * 1e9 / s, same}'
}
echo
echo "| farm | batch | wall s | Msamples/s | coordinator CPU-s / Gsample | MB written / Gsample | same bits as render |"
echo "|---|---:|---:|---:|---:|---:|---|"
t0=$(now); "$T" render "$SCENE" --spp "$SPP" --threads "$CORES" --output "$WORK/local2.exr" >/dev/null; t1=$(now)
awk -v wall="$(minus "$t1" "$t0")" -v s="$SAMPLES" -v c="$CORES" 'BEGIN {printf "| tessera render, %d threads | rule | %.2f | %.2f | – | – | – |\n", c, wall, s / wall / 1e6}'
for batch in ${BATCHES:-rule}; do
  farm 1 "$batch"
  farm 2 "$batch"
  [ "$CORES" -lt 4 ] || farm 4 "$batch"
done
