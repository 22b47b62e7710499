//! Writing a run's report folder: CSV time series and `metrics.json` (the figures are
//! [`crate::plots`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use thiserror::Error;

/// Errors writing a report.
#[derive(Debug, Error)]
pub enum ReportError {
    #[error("cannot write {path}: {reason}")]
    Io { path: String, reason: String },
    #[error("plot {path}: {reason}")]
    Plot { path: String, reason: String },
    #[error("series {name:?} has {got} samples, the time axis has {expected}")]
    Length { name: String, expected: usize, got: usize },
}

/// Named columns over one time axis.
#[derive(Debug, Clone, Default)]
pub struct TimeSeries {
    pub time: Vec<f64>,
    pub columns: Vec<(String, Vec<f64>)>,
}

impl TimeSeries {
    /// A series with the given column names.
    pub fn with_columns(names: &[String]) -> Self {
        TimeSeries {
            time: Vec::new(),
            columns: names.iter().map(|n| (n.clone(), Vec::new())).collect(),
        }
    }

    /// Append one row (one value per column, in order).
    pub fn push(&mut self, t: f64, row: &[f64]) {
        self.time.push(t);
        for (c, v) in self.columns.iter_mut().zip(row) {
            c.1.push(*v);
        }
    }

    /// Keep every other row (the first, the third, ...): half the rate over the same span.
    pub fn halve(&mut self) {
        fn every_other(v: &mut Vec<f64>) {
            let mut k = 0;
            v.retain(|_| {
                k += 1;
                k % 2 == 1
            });
        }
        every_other(&mut self.time);
        for (_, c) in &mut self.columns {
            every_other(c);
        }
    }

    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.columns.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_slice())
    }

    fn check(&self) -> Result<(), ReportError> {
        for (name, v) in &self.columns {
            if v.len() != self.time.len() {
                return Err(ReportError::Length {
                    name: name.clone(),
                    expected: self.time.len(),
                    got: v.len(),
                });
            }
        }
        Ok(())
    }

    /// Write as CSV with a `t` column first, values in single precision.
    pub fn write_csv(&self, path: &Path) -> Result<(), ReportError> {
        self.check()?;
        let io = |e: std::io::Error| ReportError::Io {
            path: path.display().to_string(),
            reason: e.to_string(),
        };
        let mut w = BufWriter::new(File::create(path).map_err(io)?);
        write!(w, "t").map_err(io)?;
        for (n, _) in &self.columns {
            write!(w, ",{n}").map_err(io)?;
        }
        writeln!(w).map_err(io)?;
        // Single precision (7 significant digits, shortest form): a 0.1 um step on a metre, a
        // thousandth of a newton; half the bytes of full precision. The metrics use f64.
        for (k, t) in self.time.iter().enumerate() {
            write!(w, "{}", *t as f32).map_err(io)?;
            for (_, v) in &self.columns {
                write!(w, ",{}", v[k] as f32).map_err(io)?;
            }
            writeln!(w).map_err(io)?;
        }
        w.flush().map_err(io)
    }
}

/// A time series of bounded length: of the rows offered it keeps one in `keep_every`, and
/// whenever it holds more than its cap it drops every other row and keeps half as many from
/// then on. A run of any length ends with between half the cap and the cap, evenly spread.
#[derive(Debug, Clone)]
pub struct BoundedSeries {
    series: TimeSeries,
    keep_every: u64,
    offered: u64,
    cap: usize,
}

impl BoundedSeries {
    pub fn new(names: &[String], keep_every: u64, cap: usize) -> BoundedSeries {
        BoundedSeries {
            series: TimeSeries::with_columns(names),
            keep_every: keep_every.max(1),
            offered: 0,
            cap: cap.max(2),
        }
    }

    /// Offer one row (one value per column, in order).
    pub fn offer(&mut self, t: f64, row: &[f64]) {
        if self.offered.is_multiple_of(self.keep_every) {
            self.series.push(t, row);
            if self.series.len() > self.cap {
                self.series.halve();
                self.keep_every *= 2;
            }
        }
        self.offered += 1;
    }

    /// Columns of a row.
    pub fn width(&self) -> usize {
        self.series.columns.len()
    }

    pub fn series(&self) -> &TimeSeries {
        &self.series
    }
}

/// Write any serialisable value as pretty JSON.
pub fn write_json<T: serde::Serialize>(value: &T, path: &Path) -> Result<(), ReportError> {
    let io = |e: String| ReportError::Io { path: path.display().to_string(), reason: e };
    let text = serde_json::to_string_pretty(value).map_err(|e| io(e.to_string()))?;
    std::fs::write(path, text + "\n").map_err(|e| io(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bounded_series_keeps_an_even_spread_under_its_cap() {
        let mut b = BoundedSeries::new(&["x".to_string()], 2, 100);
        for k in 0..10_000u32 {
            b.offer(f64::from(k), &[f64::from(k)]);
        }
        let s = b.series();
        assert!(s.len() > 50 && s.len() <= 100, "{}", s.len());
        let steps: std::collections::BTreeSet<u64> =
            s.time.windows(2).map(|w| (w[1] - w[0]) as u64).collect();
        assert_eq!(steps.len(), 1, "one spacing: {steps:?}");
        assert_eq!(s.time[0], 0.0);
        assert!(s.time[s.len() - 1] > 9_000.0, "up to the end");
        assert_eq!(s.column("x").expect("x"), s.time.as_slice());
    }

    #[test]
    fn csv_is_written() {
        let dir = std::env::temp_dir().join(format!("report-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let names: Vec<String> = ["x_des", "x_mrt"].iter().map(|s| s.to_string()).collect();
        let mut ts = TimeSeries::with_columns(&names);
        for k in 0..100 {
            let t = k as f64 * 0.01;
            ts.push(t, &[t.sin(), t.sin() + 0.01]);
        }
        ts.write_csv(&dir.join("ts.csv")).unwrap();
        let csv = std::fs::read_to_string(dir.join("ts.csv")).unwrap();
        assert_eq!(csv.lines().count(), 101);
        assert!(csv.starts_with("t,x_des,x_mrt\n0,0,0.01\n"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
