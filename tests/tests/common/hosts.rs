//! Test hosts (Linux network namespaces joined by veth pairs, `launch::hosts`) for the
//! tests that need them, or a failure that says what is missing.
//!
//! Such a test fails when the hosts cannot be made here (not root, no `ip`, no nftables),
//! naming the reason. Only with [`SKIP_VARIABLE`] set to `1` does it skip instead; it then says
//! so on stderr and lists itself with the skipped checks ([`super::skip`]). CI never sets the
//! variable.

use std::sync::Arc;

use launch::hosts::TestHosts;
use launch::launcher::host_names;

/// The variable that lets the tests needing test hosts skip where they cannot be made.
pub const SKIP_VARIABLE: &str = "TEAM_TESTS_SKIP_HOSTS";

/// Whether test hosts can be made here for `test`: `false` when they cannot and
/// [`SKIP_VARIABLE`] says to skip it. Panics, naming the reason, when they cannot otherwise.
pub fn available_or_skip(test: &str) -> bool {
    match TestHosts::check() {
        Ok(()) => true,
        Err(e) if std::env::var(SKIP_VARIABLE).as_deref() == Ok("1") => {
            eprintln!("SKIPPED {test}: {e} ({SKIP_VARIABLE}=1)");
            super::skip::record(test, &e.to_string());
            false
        }
        Err(e) => panic!("{test} needs test hosts, and they cannot be made here: {e}. Run as root with `ip` and nftables (scripts/setup-testhosts.sh installs them), or set {SKIP_VARIABLE}=1 to skip the tests that need them"),
    }
}

/// Test hosts for robots `ids` (with the coordinator's and the sim-bridge's), up; `None` when
/// [`available_or_skip`] says to skip `test`.
pub fn hosts_or_skip(ids: &[String], test: &str) -> Option<Arc<TestHosts>> {
    available_or_skip(test)
        .then(|| Arc::new(TestHosts::up(&host_names(ids)).expect("test hosts up")))
}
