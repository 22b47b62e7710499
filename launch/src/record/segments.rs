//! A recording split into files of bounded size: the run writes `run.mcap`, and each time it
//! passes [`Split::bytes`] the file is closed and renamed `run.0001.mcap`, `run.0002.mcap`,
//! ... (in the order they were written), and a new `run.mcap` goes on. With [`Split::keep`]
//! only that many closed files are kept besides the one being written: the oldest go, and the
//! disk a run takes is bounded whatever its length. `team report run.mcap` reads every file of
//! a split recording in order; it refuses one whose earlier files are gone.

use std::path::{Path, PathBuf};

/// Where a recording splits, and how many closed files it keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Split {
    /// A file is closed once it holds this many bytes (the compressed chunks written so far;
    /// a chunk is at most 1 MiB).
    pub bytes: u64,
    /// Closed files kept besides the one being written (`None`: all).
    pub keep: Option<u64>,
}

/// The `k`-th closed file (from 1) of the recording at `path`: `run.mcap` -> `run.0001.mcap`.
pub fn segment_path(path: &Path, k: u64) -> PathBuf {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("mcap");
    path.with_extension(format!("{k:04}.{ext}"))
}

/// Messages written between two looks at the file's size.
pub const CHECK_EVERY: u64 = 1024;

/// The files a splitting recorder has closed.
#[derive(Debug)]
pub struct Segments {
    path: PathBuf,
    split: Split,
    /// Files closed so far.
    pub closed: u64,
    written: u64,
}

impl Segments {
    pub fn new(path: &Path, split: Split) -> Segments {
        Segments { path: path.to_path_buf(), split, closed: 0, written: 0 }
    }

    /// The recording's path (the file being written).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One more message written: whether the file being written is due to close.
    pub fn due(&mut self) -> bool {
        self.written += 1;
        if !self.written.is_multiple_of(CHECK_EVERY) {
            return false;
        }
        std::fs::metadata(&self.path).is_ok_and(|m| m.len() >= self.split.bytes)
    }

    /// The file being written was closed: rename it to the next segment, and remove the
    /// closed files past [`Split::keep`]. The new segment's path.
    pub fn closed_one(&mut self) -> std::io::Result<PathBuf> {
        self.closed += 1;
        let to = segment_path(&self.path, self.closed);
        std::fs::rename(&self.path, &to)?;
        if let Some(keep) = self.split.keep {
            if let Some(old) = self.closed.checked_sub(keep).filter(|k| *k > 0) {
                match std::fs::remove_file(segment_path(&self.path, old)) {
                    Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
                    _ => {}
                }
            }
        }
        Ok(to)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_are_numbered_and_the_oldest_go_past_keep() {
        let dir = std::env::temp_dir().join(format!("segments-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("run.mcap");
        assert_eq!(segment_path(&path, 3), dir.join("run.0003.mcap"));
        let mut s = Segments::new(&path, Split { bytes: 10, keep: Some(2) });
        for k in 1..=4 {
            std::fs::write(&path, vec![0u8; 20]).unwrap();
            let due = (0..CHECK_EVERY).map(|_| s.due()).last();
            assert_eq!(due, Some(true), "a file past the split is due");
            assert_eq!(s.closed_one().unwrap(), segment_path(&path, k));
        }
        let left: Vec<bool> = (1..=4).map(|k| segment_path(&path, k).exists()).collect();
        assert_eq!(left, vec![false, false, true, true], "the two newest kept");
        std::fs::write(&path, vec![0u8; 5]).unwrap();
        assert!(!(0..CHECK_EVERY).any(|_| s.due()), "a small file is not due");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
