#!/usr/bin/env bash
# A series of real-time runs of one scenario at the real-time defaults (`team run --realtime`
# with no keys set: the team loop at 250 Hz, drive commands with gains and a trajectory, the
# delay from the latency; docs/realtime.md), one after another. Per run: every check passed or
# not, the object's error, the worst robot's deadline misses, drive gaps (physics steps without
# a valid drive command, summed over the robots), the state-to-torque latency and the real-time
# factor; then how many runs passed every check with no drive gap. Name the machine and its
# load (printed) with the figures.
#
#   ./scripts/realtime-series.sh                                    # S4, embedded, 10 runs
#   MODE=--distributed ./scripts/realtime-series.sh                 # every component a process
#   MODE=--hosts ./scripts/realtime-series.sh                       # each on a test host (root)
#   BUSY=2 RUNS=5 MODE=--distributed ./scripts/realtime-series.sh   # beside two busy loops
#   SCENARIO=scenarios/team4_cube.toml SETS="duration=60" ./scripts/realtime-series.sh
#
# SCENARIO: the scenario file (default S4). RUNS: how many (default 10). MODE: `--distributed`,
# `--hosts` or empty (embedded). BUSY: busy loops to run beside (default 0). SETS: scenario keys
# for every run (`SETS="team_hz=500"`). Needs the release binaries (cargo build --release
# --bins). Reports go to reports/series/.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

scenario=${SCENARIO:-scenarios/s4_object_circle.toml}
runs=${RUNS:-10}
mode=${MODE:-}
busy_n=${BUSY:-0}
team=./target/release/team
[[ -x "$team" ]] || { echo "realtime-series: build first: cargo build --release --bins" >&2; exit 1; }

busy=()
trap '[[ ${#busy[@]} -eq 0 ]] || kill "${busy[@]}" 2>/dev/null || true' EXIT
for ((i = 0; i < busy_n; i++)); do
    ( while :; do :; done ) &
    busy+=($!)
done

name=$(basename "$scenario" .toml)
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg), ${busy_n} busy loops beside"
echo "series: $name, real time ${mode:-embedded} at the defaults${SETS:+, $SETS}, $runs runs"
printf '%4s %7s %17s %13s %10s %15s %5s\n' run checks "object rms/max" "worst misses" "drive gaps" "latency p50/99" rtf
passed=0
for ((k = 1; k <= runs; k++)); do
    args=(--realtime --no-record --quiet)
    for kv in ${SETS:-}; do args+=(--set "$kv"); done
    # shellcheck disable=SC2206
    [[ -z "$mode" ]] || args+=($mode)
    out="reports/series/${name}${mode:+-${mode#--}}-$k"
    mkdir -p "$out"
    rm -f "$out/metrics.json"
    # A run that fails its checks still writes its report; the table says which.
    "$team" run "$scenario" "${args[@]}" --out "$out" >"$out/log.txt" 2>&1 || true
    if python3 - "$out/metrics.json" "$k" <<'PY'; then passed=$((passed + 1)); fi
import json, sys
path, k = sys.argv[1:3]
try:
    m = json.load(open(path))
except (OSError, ValueError) as e:
    print(f"{k:>4} no report: {e} (see {path.rsplit('/', 1)[0]}/log.txt)")
    sys.exit(1)
loop = (m.get("loop_timing") or {}).get("robots", {})
worst = max(loop.values(), key=lambda r: r["deadline_misses"], default=None)
misses = f"{worst['deadline_misses']}/{worst['ticks']}" if worst else "-"
gaps = sum(r.get("drive_gaps", 0) for r in loop.values())
lat = max((r["latency_us"] for r in loop.values()), key=lambda p: p["p99"], default=None)
lat_s = f"{lat['p50']/1e3:.2f}/{lat['p99']/1e3:.2f} ms" if lat else "-"
obj = m.get("object") or {}
obj_s = f"{obj.get('position_rms_m', float('nan'))*1e3:.2f}/{obj.get('position_max_m', float('nan'))*1e3:.2f} mm"
checks = m.get("checks", [])
ok = sum(1 for c in checks if c["passed"])
rtf = m.get("real_time_factor")
rtf_s = f"{rtf:.2f}" if rtf is not None else "-"
print(f"{k:>4} {ok:>3}/{len(checks):<3} {obj_s:>17} {misses:>13} {gaps:>10} {lat_s:>15} {rtf_s:>5}")
sys.exit(0 if ok == len(checks) and checks and gaps == 0 else 1)
PY
done
echo "every check and no drive gap: $passed of $runs"
