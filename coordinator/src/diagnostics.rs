//! Per-tick diagnostics kept for reports: a bounded history of [`TickDiagnostics`] with
//! summary statistics (the service publishes each one on `keys::diagnostics(team)`).

use std::collections::VecDeque;

use protocol::{QpStatus, TickDiagnostics};

/// A ring buffer of the last `capacity` ticks' diagnostics.
#[derive(Debug, Clone)]
pub struct DiagnosticsLog {
    capacity: usize,
    ticks: VecDeque<TickDiagnostics>,
    /// Ticks whose QP was not solved (the fallback ran), all time.
    pub fallbacks: u64,
    pub total: u64,
}

impl DiagnosticsLog {
    pub fn new(capacity: usize) -> Self {
        DiagnosticsLog { capacity: capacity.max(1), ticks: VecDeque::new(), fallbacks: 0, total: 0 }
    }

    pub fn push(&mut self, d: TickDiagnostics) {
        self.total += 1;
        if !matches!(d.qp_status, QpStatus::Solved | QpStatus::AlmostSolved) {
            self.fallbacks += 1;
        }
        if self.ticks.len() == self.capacity {
            self.ticks.pop_front();
        }
        self.ticks.push_back(d);
    }

    pub fn ticks(&self) -> impl Iterator<Item = &TickDiagnostics> {
        self.ticks.iter()
    }

    /// Percentile (0..=100) of the total tick time over the kept ticks, µs.
    pub fn total_us_percentile(&self, pct: f64) -> Option<f64> {
        let mut v: Vec<f64> = self.ticks.iter().map(|d| d.total_us).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(|a, b| a.total_cmp(b));
        let i = ((pct / 100.0) * (v.len() - 1) as f64).round() as usize;
        Some(v[i.min(v.len() - 1)])
    }
}
