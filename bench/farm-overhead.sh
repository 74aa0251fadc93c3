#!/usr/bin/env bash
# Farm overhead: the same job rendered by `tessera render` and by a coordinator plus one worker
# on loopback, on the same machine, alternating runs. Reports the throughput ratio, the bytes
# the worker sent per sample, the coordinator's CPU time (as a share of the job's wall time and
# per 10^9 samples), the bytes it wrote to disk per 10^9 samples, and the worker's utilisation.
#
#   bench/farm-overhead.sh [SCENE] [SPP] [RUNS]   (writes docs/benchmarks/farm-overhead-SPPspp.md)
#
# BATCH=B passes --batch B to both (default: the unit rule's batch); CHECKPOINT=S passes
# --checkpoint-interval S to the coordinator; TILE=N --tile-size N to the farm job; OUT=FILE
# names the report; GUIDING=1 renders with --guiding in both (a guided job: epochs, their
# barriers, training trees sent and merged, guides fetched); TESSERA=BINARY uses that build
# instead of building one (a machine without cargo).
set -euo pipefail
cd "$(dirname "$0")/.."
SCENE=${1:-scenes/cornell-box.toml}
SPP=${2:-256}
RUNS=${3:-3}
TILE=${TILE:-}   # tile edge for the farm job (default: the coordinator's)
BATCH=${BATCH:-}
CHECKPOINT=${CHECKPOINT:-}
GUIDING=${GUIDING:-}
OUT=${OUT:-docs/benchmarks/farm-overhead-${SPP}spp${TILE:+-tile$TILE}${BATCH:+-batch$BATCH}${CHECKPOINT:+-checkpoint$CHECKPOINT}${GUIDING:+-guiding}.md}
THREADS=$(nproc)
if [ -n "${TESSERA:-}" ]; then T=$(realpath "$TESSERA"); else
  cargo build --release -q -p tessera-cli
  T=$PWD/target/release/tessera
fi
WORK=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$WORK"' EXIT
TICK=$(getconf CLK_TCK)

cpu_ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
wchar() { awk '/^wchar/ {print $2}' "/proc/$1/io"; }
disk_writes() { awk '/^write_bytes/ {print $2}' "/proc/$1/io"; }
now() { date +%s.%N; }

pixels=$(grep -E '^(width|height)' "$SCENE" | awk '{p = (NR == 1 ? $3 : p * $3)} END {print p}')
gsamples=$(echo "$pixels * $SPP / 1000000000" | bc -l)
local_s=(); farm_s=(); bytes=(); share=(); cpu_g=(); disk_g=(); util=()
for run in $(seq "$RUNS"); do
  t0=$(now)
  "$T" render "$SCENE" --spp "$SPP" ${BATCH:+--batch "$BATCH"} ${GUIDING:+--guiding} --threads "$THREADS" --output "$WORK/local.exr" >/dev/null 2>&1
  t1=$(now)
  local_s+=("$(echo "$t1 - $t0" | bc -l)")

  rm -rf "$WORK/data"
  "$T" coordinator --listen 127.0.0.1:0 --data-dir "$WORK/data" ${CHECKPOINT:+--checkpoint-interval "$CHECKPOINT"} >"$WORK/coord.out" 2>/dev/null &
  cpid=$!
  until grep -q listening "$WORK/coord.out" 2>/dev/null; do sleep 0.05; done
  url="http://$(sed -n 's/listening on //p' "$WORK/coord.out")"
  "$T" worker --coordinator "$url" --threads "$THREADS" 2>/dev/null &
  wpid=$!
  sleep 0.5
  c0=$(cpu_ticks $cpid); w0=$(wchar $wpid); d0=$(disk_writes $cpid); u0=$(cpu_ticks $wpid)
  t0=$(now)
  "$T" submit "$SCENE" --coordinator "$url" --spp "$SPP" ${BATCH:+--batch "$BATCH"} ${GUIDING:+--guiding} ${TILE:+--tile-size "$TILE"} --wait --output "$WORK/farm.exr" >/dev/null 2>&1
  t1=$(now)
  c1=$(cpu_ticks $cpid); w1=$(wchar $wpid); d1=$(disk_writes $cpid); u1=$(cpu_ticks $wpid)
  batch=$("$T" status --coordinator "$url" --json 2>/dev/null | grep -o '"batch": *[0-9]*' | head -1 | grep -o '[0-9]*$' || true)
  kill $wpid; wait $wpid || true; kill $cpid; wait $cpid || true
  cmp -s "$WORK/farm.exr" "$WORK/local.exr" || { echo "farm EXR differs from the local one" >&2; exit 1; }
  wall=$(echo "$t1 - $t0" | bc -l)
  farm_s+=("$wall")
  bytes+=("$(echo "($w1 - $w0) / ($pixels * $SPP)" | bc -l)")
  share+=("$(echo "($c1 - $c0) / $TICK / $wall * 100" | bc -l)")
  cpu_g+=("$(echo "($c1 - $c0) / $TICK / $gsamples" | bc -l)")
  disk_g+=("$(echo "($d1 - $d0) / 1000000 / $gsamples" | bc -l)")
  util+=("$(echo "($u1 - $u0) / $TICK / ($wall * $THREADS) * 100" | bc -l)")
  echo "run $run: local ${local_s[-1]} s, farm $wall s" >&2
done

median() { printf '%s\n' "$@" | sort -g | awk '{a[NR] = $1} END {print a[int((NR + 1) / 2)]}'; }
L=$(median "${local_s[@]}"); F=$(median "${farm_s[@]}")
B=$(median "${bytes[@]}"); S=$(median "${share[@]}")
CG=$(median "${cpu_g[@]}"); DG=$(median "${disk_g[@]}"); U=$(median "${util[@]}")
RATIO=$(echo "$L / $F" | bc -l)
if [ -n "$BATCH" ]; then BATCH_NOTE=$BATCH; else BATCH_NOTE="${batch:-?}, the unit rule's"; fi
CPU=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')
{
  echo "# Farm overhead"
  echo
  echo "Command: \`${GUIDING:+GUIDING=$GUIDING }${TILE:+TILE=$TILE }${BATCH:+BATCH=$BATCH }${CHECKPOINT:+CHECKPOINT=$CHECKPOINT }bench/farm-overhead.sh $SCENE $SPP $RUNS\` ($(date -u +%Y-%m-%d))."
  echo
  echo "Machine: $CPU, $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo); $THREADS render threads in both runs."
  echo
  echo "Job: \`$SCENE\` at $SPP spp${GUIDING:+ with --guiding (both runs)}, tile ${TILE:-128 (the default)}, batch $BATCH_NOTE, checkpoint interval ${CHECKPOINT:-5 (the default)} s; medians of $RUNS alternating runs."
  echo "The farm's EXR was checked byte-identical to the local one in every run."
  echo
  echo "| measure | value |"
  echo "|---|---|"
  printf '| `tessera render` wall time | %.3f s |\n' "$L"
  printf '| coordinator + 1 worker, `submit --wait` wall time | %.3f s |\n' "$F"
  printf '| **throughput ratio farm / local** (target ≥ 0.97) | **%.3f** |\n' "$RATIO"
  printf '| bytes the worker wrote per sample | %.3f |\n' "$B"
  printf '| coordinator CPU time / job wall time | %.2f %% |\n' "$S"
  printf '| coordinator CPU-s per Gsample | %.3f |\n' "$CG"
  printf '| coordinator disk writes per Gsample | %.1f MB |\n' "$DG"
  printf '| worker utilisation (its CPU time / wall time × threads) | %.1f %% |\n' "$U"
  echo
  echo "Runs (s): local ${local_s[*]}; farm ${farm_s[*]}."
  echo
  echo "The farm's wall time includes submitting, the worker's first lease and scene fetch,"
  echo "writing the EXR on the coordinator and streaming it back to the client."
} > "$OUT"
cat "$OUT"
