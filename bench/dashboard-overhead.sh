#!/usr/bin/env bash
# Dashboard overhead: the farm-overhead job (a coordinator and one worker on loopback,
# `submit --wait`) run with no dashboard, and with `--http` and VIEWERS people watching the
# job page (bench/dashboard-viewer.py: the page's requests, JSON every second and a new
# preview as results come in), alternating runs. Reports the throughput ratio and the
# coordinator's CPU time in each.
#
#   bench/dashboard-overhead.sh [SCENE] [SPP] [RUNS] [VIEWERS]  (writes docs/benchmarks/dashboard-overhead.md)
set -euo pipefail
cd "$(dirname "$0")/.."
SCENE=${1:-scenes/cornell-box.toml}
SPP=${2:-256}
RUNS=${3:-5}
VIEWERS=${4:-3}
THREADS=$(nproc)
cargo build --release -q -p tessera-cli
T=$PWD/target/release/tessera
WORK=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$WORK"' EXIT
TICK=$(getconf CLK_TCK)

cpu_ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
now() { date +%s.%N; }

# One farm run; $1 = "off" or "on". Prints "wall coordinator_cpu_share viewer_cpu_share".
farm_run() {
  rm -rf "$WORK/data"
  local http=()
  [ "$1" = on ] && http=(--http 127.0.0.1:0)
  "$T" coordinator --listen 127.0.0.1:0 "${http[@]}" --data-dir "$WORK/data" >"$WORK/coord.out" 2>/dev/null &
  local cpid=$!
  until grep -q listening "$WORK/coord.out" 2>/dev/null; do sleep 0.05; done
  [ "$1" = on ] && until grep -q dashboard "$WORK/coord.out" 2>/dev/null; do sleep 0.05; done
  local url="http://$(sed -n 's/listening on //p' "$WORK/coord.out")"
  "$T" worker --coordinator "$url" --threads "$THREADS" 2>/dev/null &
  local wpid=$!
  local vpid=""
  if [ "$1" = on ]; then
    # A fresh data directory's first job is job-000001: the viewers wait for it to appear.
    python3 bench/dashboard-viewer.py "$(sed -n 's/dashboard on //p' "$WORK/coord.out")" job-000001 "$VIEWERS" >"$WORK/viewer.out" 2>&1 &
    vpid=$!
  fi
  sleep 0.5
  local c0 v0=0 t0 t1 c1 v1=0
  c0=$(cpu_ticks $cpid); [ -n "$vpid" ] && v0=$(cpu_ticks $vpid)
  t0=$(now)
  "$T" submit "$SCENE" --coordinator "$url" --spp "$SPP" --wait --output "$WORK/farm-$1.exr" >/dev/null 2>&1
  t1=$(now)
  c1=$(cpu_ticks $cpid); [ -n "$vpid" ] && v1=$(cpu_ticks $vpid)
  [ -n "$vpid" ] && { wait $vpid || true; cat "$WORK/viewer.out" >&2; }
  kill $wpid; wait $wpid || true; kill $cpid; wait $cpid || true
  local wall; wall=$(echo "$t1 - $t0" | bc -l)
  echo "$wall $(echo "($c1 - $c0) / $TICK / $wall * 100" | bc -l) $(echo "($v1 - $v0) / $TICK / $wall * 100" | bc -l)"
}

off_s=(); on_s=(); off_cpu=(); on_cpu=(); viewer_cpu=()
for run in $(seq "$RUNS"); do
  read -r w c _ < <(farm_run off); off_s+=("$w"); off_cpu+=("$c")
  read -r w c v < <(farm_run on); on_s+=("$w"); on_cpu+=("$c"); viewer_cpu+=("$v")
  cmp -s "$WORK/farm-off.exr" "$WORK/farm-on.exr" || { echo "the EXRs differ" >&2; exit 1; }
  echo "run $run: no dashboard ${off_s[-1]} s, dashboard watched ${on_s[-1]} s" >&2
done

median() { printf '%s\n' "$@" | sort -g | awk '{a[NR] = $1} END {print a[int((NR + 1) / 2)]}'; }
OFF=$(median "${off_s[@]}"); ON=$(median "${on_s[@]}")
RATIO=$(echo "$OFF / $ON" | bc -l)
# Each pair's ratio, and their mean: the machine's speed drifts between pairs more than the
# dashboard costs, so the spread says how far the ratio can be trusted.
pairs=(); for i in "${!off_s[@]}"; do pairs+=("$(printf '%.3f' "$(echo "${off_s[$i]} / ${on_s[$i]}" | bc -l)")"); done
MEAN_PAIR=$(printf '%s\n' "${pairs[@]}" | awk '{s += $1} END {printf "%.3f", s / NR}')
CPU_OFF=$(median "${off_cpu[@]}"); CPU_ON=$(median "${on_cpu[@]}")
CPU=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')
{
  echo "# Dashboard overhead"
  echo
  echo "Command: \`bench/dashboard-overhead.sh $SCENE $SPP $RUNS $VIEWERS\` ($(date -u +%Y-%m-%d))."
  echo
  echo "Machine: $CPU, $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo); $THREADS render threads in both runs."
  echo
  echo "Job: \`$SCENE\` at $SPP spp on a coordinator and one worker (the farm-overhead job), run"
  echo "with no dashboard and with \`--http\` and $VIEWERS viewers of the job page"
  echo "(\`bench/dashboard-viewer.py\`, on the same machine); medians of $RUNS alternating runs."
  echo "The two runs' EXRs were checked byte-identical every time."
  echo
  echo "| measure | value |"
  echo "|---|---|"
  printf '| wall time, no dashboard | %.3f s |\n' "$OFF"
  printf '| wall time, dashboard watched by %s | %.3f s |\n' "$VIEWERS" "$ON"
  printf '| **throughput ratio watched / not** (target ≥ 0.98) | **%.3f** |\n' "$RATIO"
  printf '| mean of the %s pairs'"'"' ratios | %s |\n' "$RUNS" "$MEAN_PAIR"
  printf '| coordinator CPU / wall, no dashboard | %.2f %% |\n' "$CPU_OFF"
  printf '| coordinator CPU / wall, watched | %.2f %% |\n' "$CPU_ON"
  printf '| **the dashboard'"'"'s CPU, as a share of the machine** (%s cores) | **%.2f %%** |\n' "$(nproc)" "$(echo "($CPU_ON - $CPU_OFF) / $(nproc)" | bc -l)"
  printf '| the viewers'"'"' own CPU / wall | %.2f %% |\n' "$(median "${viewer_cpu[@]}")"
  echo
  echo "Runs (s): no dashboard ${off_s[*]}; watched ${on_s[*]}."
  echo "Pairs' ratios: ${pairs[*]}."
} > docs/benchmarks/dashboard-overhead.md
cat docs/benchmarks/dashboard-overhead.md
