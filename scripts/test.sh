#!/usr/bin/env bash
# Run every test of the workspace, on a fresh machine too: provisions MuJoCo, the Python
# client's environment (eclipse-zenoh, pinned) and what the test hosts need (nftables), builds the
# binaries the multi-process tests start, then runs all tests in release mode (numeric code
# and simulations are slow unoptimised). Building bins and tests in one invocation gives
# them the same feature set, so `cargo test` reuses the build. Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup-mujoco.sh
./scripts/setup-python-client.sh
./scripts/setup-testhosts.sh
cargo build --release --workspace --bins --tests --locked
cargo test --release --workspace --locked "$@"
