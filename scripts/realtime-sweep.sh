#!/usr/bin/env bash
# The rates a team keeps against the wall clock, and what latency and loss cost: runs each
# scenario with `team run --realtime` (whole stack, MuJoCo in the loop) for every combination
# of robot rate, team rate, team delay and packet loss, and prints per run: the deadline misses
# of the worst robot, the state-to-torque latency, the coordinator's tick, the real-time
# factor, the object's error (RMS and max), whether the object was held, and the acceptance
# checks passed. A loop that falls a whole period behind slips its schedule, so a run whose
# factor is well below 1 did not keep its rate. Take it on an idle machine and name the
# machine and its load (the script prints both).
#
#   ./scripts/realtime-sweep.sh                      # 2, 4 and 8 robots at 125, 250, 500, 1000 Hz, 5 s each
#   DURATION=60 SCENARIOS=s4_object_circle RATES=1000 ./scripts/realtime-sweep.sh
#   MODE=--distributed ./scripts/realtime-sweep.sh   # every component its own process
#   SCENARIOS=s4_object_circle RATES=1000 TEAM_RATES="1000 500 250" DELAYS="0 1 2 3" \
#       DURATION=10 MODE=--distributed ./scripts/realtime-sweep.sh      # team rate x delay
#   SCENARIOS=s4_object_circle RATES=1000 TEAM_RATES=500 DELAYS="1 2" LOSS="0 5 10" \
#       DURATION=10 MODE=--hosts ./scripts/realtime-sweep.sh            # x loss on r1's link (root)
#
# Keys the sweep does not set take the real-time defaults (docs/realtime.md: drive gains with a
# trajectory, the delay from the latency). TEAM_RATES: the team loop's rates (`team_hz`; in real
# time the team's rate is the control rate and the drives fill the physics steps between, so
# the run's rate is the team's; "-" runs at RATES). DELAYS: `team_delay_ticks` (`auto` prints as autoN, N the
# longest delay an agent came to). LOSS: percent of robot r1's packets
# dropped on its link (`team run --hosts --loss r1=P`; needs MODE=--hosts). SETS: more
# scenario keys for every run (`SETS="predict_delay=false"`). RECORD=1 records
# each run (run.mcap; the default runs without, `--no-record`). Needs the release
# binaries (cargo build --release --bins). Reports go to reports/sweep/.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

duration=${DURATION:-5}
scenarios=${SCENARIOS:-"s4_object_circle team4_cube team8_beam"}
rates=${RATES:-"125 250 500 1000"}
team_rates=${TEAM_RATES:--}
delays=${DELAYS:-0}
losses=${LOSS:-0}
mode=${MODE:-}
team=./target/release/team
[[ -x "$team" ]] || { echo "realtime-sweep: build first: cargo build --release --bins" >&2; exit 1; }
for loss in $losses; do
    [[ "$loss" == 0 || "$mode" == --hosts ]] || { echo "realtime-sweep: LOSS needs MODE=--hosts (the loss is on a test host's link)" >&2; exit 1; }
done

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "mode: realtime ${mode:-embedded}, ${duration} s per run"
printf '%-18s %5s %5s %6s %4s %6s %13s %15s %15s %5s %17s %5s %7s\n' \
    scenario Hz team d loss robots "worst misses" "latency p50/99" "tick p50/99" rtf "object rms/max" held checks
for s in $scenarios; do
  for hz in $rates; do
    for th in $team_rates; do
      for d in $delays; do
        for loss in $losses; do
            args=(--realtime --set "control_hz=$hz" --set "duration=$duration" --set "team_delay_ticks=$d")
            [[ "$th" == - ]] || args+=(--set "team_hz=$th")
            [[ "$loss" == 0 ]] || args+=(--loss "r1=$loss")
            for kv in ${SETS:-}; do args+=(--set "$kv"); done
            [[ "${RECORD:-0}" == 1 ]] || args+=(--no-record)
            # shellcheck disable=SC2206
            [[ -z "$mode" ]] || args+=($mode)
            out="reports/sweep/${s}-${hz}-team${th/-/$hz}-d${d}-loss${loss}${mode:+-${mode#--}}"
            mkdir -p "$out"
            rm -f "$out/metrics.json"
            # A run that fails its checks still writes its report; the table says which.
            "$team" run "scenarios/$s.toml" "${args[@]}" --quiet --out "$out" >"$out/log.txt" 2>&1 || true
            python3 - "$out/metrics.json" "$s" "$hz" "${th/-/$hz}" "$d" "$loss" <<'PY'
import json, sys
path, scenario, hz, th, d, loss = sys.argv[1:7]
head = f"{scenario:<18} {hz:>5} {th:>5} {d:>6} {loss:>3}%"
try:
    m = json.load(open(path))
except (OSError, ValueError) as e:
    print(f"{head} no report: {e} (see {path.rsplit('/', 1)[0]}/log.txt)")
    sys.exit(0)
if m.get("team_delay_auto"):
    d = f"auto{m.get('team_delay_ticks', '?')}"
    head = f"{scenario:<18} {hz:>5} {th:>5} {d:>6} {loss:>3}%"
loop = (m.get("loop_timing") or {}).get("robots", {})
worst = max(loop.items(), key=lambda kv: kv[1]["deadline_misses"], default=(None, None))
misses = f"{worst[1]['deadline_misses']}/{worst[1]['ticks']}" if worst[0] else "-"
lat = max((r["latency_us"] for r in loop.values()), key=lambda p: p["p99"], default=None)
lat_s = f"{lat['p50']/1e3:.2f}/{lat['p99']/1e3:.2f} ms" if lat else "-"
tick = m.get("controller_tick_us") or {}
tick_s = f"{tick.get('p50', 0)/1e3:.2f}/{tick.get('p99', 0)/1e3:.2f} ms" if tick else "-"
obj = m.get("object") or {}
obj_s = f"{obj.get('position_rms_m', float('nan'))*1e3:.2f}/{obj.get('position_max_m', float('nan'))*1e3:.2f} mm"
held = "no" if (m.get("drop") or {}).get("dropped") else "yes"
checks = m.get("checks", [])
ok = sum(1 for c in checks if c["passed"])
rtf = m.get("real_time_factor")
rtf_s = f"{rtf:.2f}" if rtf is not None else "-"
print(f"{head} {len(loop):>6} {misses:>13} {lat_s:>15} {tick_s:>15} {rtf_s:>5} {obj_s:>17} {held:>5} {ok}/{len(checks)}")
PY
        done
      done
    done
  done
done
