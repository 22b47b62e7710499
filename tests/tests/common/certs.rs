//! Test certificates for the TLS tests: a fresh test CA and one certificate per identity,
//! made by the repository's `scripts/make-test-certs.sh` (fails loudly without openssl).
//! Self-contained, so that examples include it too (`#[path]`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// A fresh folder `{tag}-{pid}` in the temporary directory with a test CA (`ca.pem`,
/// `ca.key`) and certificates for the coordinator, `robots`, the sim-bridge, the runner and
/// the tool.
pub fn make(tag: &str, robots: &[&str]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/make-test-certs.sh");
    let out = Command::new(&script)
        .arg(&dir)
        .args(robots)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", script.display()));
    assert!(
        out.status.success(),
        "make-test-certs.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}
