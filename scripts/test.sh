#!/usr/bin/env bash
# Run every test of the workspace, on a fresh machine too: provisions MuJoCo, the Python
# client's environment (eclipse-zenoh, pinned) and what the test hosts need (nftables), checks
# the formatting and clippy's lints, builds the binaries the multi-process tests start, then
# runs all tests in release mode (numeric code and simulations are slow unoptimised). The
# binaries alone (`scripts/demo.sh`) and the binaries with the tests resolve the same features
# (the test crate's dependencies carry what the tests add), so neither build redoes the other's.
#
# Without arguments it then runs the fault, real-time and test-host tests once more with two
# busy loops beside them (recovery must not depend on the machine's load). Extra arguments go
# to `cargo test` instead, and the loaded run is left out. The last line lists every check
# that was skipped (`TEAM_TESTS_SKIP_HOSTS=1` lets the tests that need test hosts skip where
# they cannot be made; without it they fail).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup-mujoco.sh
./scripts/setup-python-client.sh
./scripts/setup-testhosts.sh
# The code's habits first: rustfmt's layout (rustfmt.toml) and clippy without a warning.
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo build --release --workspace --bins --tests --locked

skipped=target/test-reports/skipped.txt
mkdir -p target/test-reports
rm -f "$skipped"
status=0
cargo test --release --workspace --locked --no-fail-fast "$@" || status=$?

if [ $# -eq 0 ]; then
    echo "== the fault, real-time and test-host tests again, with two busy loops beside them"
    busy=()
    for _ in 1 2; do
        ( while :; do :; done ) &
        busy+=($!)
    done
    trap 'kill "${busy[@]}" 2>/dev/null || true' EXIT
    cargo test --release --workspace --locked --no-fail-fast --test faults --test realtime --test hosts || status=$?
    kill "${busy[@]}" 2>/dev/null || true
fi

if [ -s "$skipped" ]; then
    echo "skipped checks: $(sort -u "$skipped" | paste -sd ';' -)"
else
    echo "skipped checks: none"
fi
exit "$status"
