#!/usr/bin/env bash
# The main job, on a fresh machine too: provisions MuJoCo, builds, and runs the team.
# Extra arguments go to `team smoke`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup-mujoco.sh
cargo build --release --workspace --bins --locked
exec ./target/release/team smoke "$@"
