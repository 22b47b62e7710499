#!/usr/bin/env bash
# The main job, on a fresh machine too: provisions MuJoCo, builds, and runs the team demo:
# the paper's experiment S1 (simultaneous torso and object motion) with the whole stack in the
# loop. The report (metrics.json, CSV time series, SVG plots) goes to reports/s1_torso_and_object/.
# Extra arguments go to `team run` (e.g. --distributed, --set duration=5).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup-mujoco.sh
cargo build --release --workspace --bins --locked
exec ./target/release/team run scenarios/s1_torso_and_object.toml "$@"
