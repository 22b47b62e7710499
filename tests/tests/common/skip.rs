//! The checks a test skipped, with the reason: one line each in [`list`], which
//! `scripts/test.sh` prints in its last line, so that a run that skipped something says so.

use std::io::Write;
use std::path::PathBuf;

/// The file the skipped checks are listed in, one per line: `target/test-reports/skipped.txt`.
pub fn list() -> PathBuf {
    super::scenario::repo().join("target/test-reports/skipped.txt")
}

/// List `test` as skipped because of `why`.
pub fn record(test: &str, why: &str) {
    let path = list();
    let _ = std::fs::create_dir_all(path.parent().expect("a folder"));
    if let Ok(mut f) = std::fs::OpenOptions::new().create(true).append(true).open(&path) {
        let _ = writeln!(f, "{test}: {why}");
    }
}
