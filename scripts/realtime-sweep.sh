#!/usr/bin/env bash
# The control rates a team keeps against the wall clock: runs each scenario with `team run
# --realtime` at each rate (embedded, whole stack, MuJoCo in the loop) and prints, per run, the
# deadline misses of the worst robot, the state-to-torque latency, the coordinator's tick and
# whether every acceptance check passed, and the real-time factor: a loop that falls a whole
# period behind slips its schedule, so a run whose factor is well below 1 did not keep the
# rate. The highest rate with zero misses and a factor near 1 is the figure the README
# reports; take it on an idle machine (name the machine and its load).
#
#   ./scripts/realtime-sweep.sh                      # 2, 4 and 8 robots at 125, 250, 500, 1000 Hz, 5 s each
#   DURATION=60 SCENARIOS=s4_object_circle RATES=1000 ./scripts/realtime-sweep.sh
#   MODE=--distributed ./scripts/realtime-sweep.sh   # every component its own process
#
# Needs the release binaries (cargo build --release --bins). Reports go to reports/sweep/.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

duration=${DURATION:-5}
scenarios=${SCENARIOS:-"s4_object_circle team4_cube team8_beam"}
rates=${RATES:-"125 250 500 1000"}
mode=${MODE:-}
team=./target/release/team
[[ -x "$team" ]] || { echo "realtime-sweep: build first: cargo build --release --bins" >&2; exit 1; }

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-18s %6s %7s %14s %18s %18s %6s %8s\n' scenario Hz robots "worst misses" "latency p50/p99" "tick p50/p99" rtf checks
for s in $scenarios; do
    for hz in $rates; do
        out="reports/sweep/${s}-${hz}${mode:+-${mode#--}}"
        mkdir -p "$out"
        # A run that fails its checks still writes its report; the table says which.
        # shellcheck disable=SC2086
        "$team" run "scenarios/$s.toml" --realtime $mode --set "control_hz=$hz" --set "duration=$duration" \
            --quiet --out "$out" >"$out/log.txt" 2>&1 || true
        python3 - "$out/metrics.json" "$s" "$hz" <<'PY'
import json, sys
path, scenario, hz = sys.argv[1:4]
try:
    m = json.load(open(path))
except (OSError, ValueError) as e:
    print(f"{scenario:<18} {hz:>6} {'-':>10} {'no report: ' + str(e)}")
    sys.exit(0)
loop = (m.get("loop_timing") or {}).get("robots", {})
worst = max(loop.items(), key=lambda kv: kv[1]["deadline_misses"], default=(None, None))
misses = f"{worst[1]['deadline_misses']}/{worst[1]['ticks']}" if worst[0] else "-"
lat = max((r["latency_us"] for r in loop.values()), key=lambda p: p["p99"], default=None)
lat_s = f"{lat['p50']/1e3:.2f}/{lat['p99']/1e3:.2f} ms" if lat else "-"
tick = m.get("controller_tick_us") or {}
tick_s = f"{tick.get('p50', 0)/1e3:.2f}/{tick.get('p99', 0)/1e3:.2f} ms" if tick else "-"
checks = m.get("checks", [])
ok = sum(1 for c in checks if c["passed"])
rtf = m.get("real_time_factor")
rtf_s = f"{rtf:.2f}" if rtf is not None else "-"
print(f"{scenario:<18} {hz:>6} {len(loop):>7} {misses:>14} {lat_s:>18} {tick_s:>18} {rtf_s:>6} {ok}/{len(checks):<6}")
PY
    done
done
