#!/usr/bin/env bash
# The resident memory of a `team run` as it goes: every INTERVAL seconds of wall time one line
# "wall_s rss_mb" (on stderr, so that the run's summary stays on stdout), then the run's summary
# and three figures: the memory after the first minute, the most after it, and the growth
# between them. A run of any length should stay flat after its first minute
# (docs/recordings.md, "Runs of any length"). Pass `team run`'s arguments:
#
#   ./scripts/memory.sh scenarios/s4_object_circle.toml --set duration=600 --no-record
#   INTERVAL=10 ./scripts/memory.sh scenarios/s4_object_circle.toml --set duration=3600 --no-record
#
# Embedded runs only (the team is one process). Needs the release binaries (cargo build
# --release --bins).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

interval=${INTERVAL:-5}
team=./target/release/team
[[ -x "$team" ]] || { echo "memory: build first: cargo build --release --bins" >&2; exit 1; }
[[ $# -gt 0 ]] || { echo "usage: scripts/memory.sh SCENARIO [team run options]" >&2; exit 2; }

"$team" run "$@" --quiet &
pid=$!
trap 'kill "$pid" 2>/dev/null || true' EXIT
start=$(date +%s)
samples=()
while kill -0 "$pid" 2>/dev/null; do
    rss=$(awk '/^VmRSS/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
    if [[ -n "$rss" ]]; then
        t=$(( $(date +%s) - start ))
        samples+=("$t $rss")
        echo "$t $(( rss / 1024 ))" >&2
    fi
    sleep "$interval"
done
rc=0
wait "$pid" || rc=$?
trap - EXIT
printf '%s\n' "${samples[@]}" | awk '
    $1 >= 60 && !base { base = $2 }
    $1 >= 60 { if ($2 > most) most = $2 }
    END {
        if (!base) { print "memory: the run ended within its first minute"; exit }
        printf "memory: %d MB after the first minute, at most %d MB after it (grew %d MB)\n",
            base / 1024, most / 1024, (most - base) / 1024
    }'
exit "$rc"
