#!/usr/bin/env bash
# Run every test of the workspace, on a fresh machine too: provisions MuJoCo, builds the
# binaries the multi-process tests start, then runs all tests in release mode (numeric code
# and simulations are slow unoptimised). Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup-mujoco.sh
cargo build --release --workspace --bins --locked
cargo test --release --workspace --locked "$@"
