//! The measures of success every report uses (`docs/scenarios.md`), computed from recorded series.
//! Inputs are plain series so that any source (ground truth, diagnostics) can feed them.

use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;

/// Root mean square of a series (0 for an empty one).
pub fn rms(xs: impl IntoIterator<Item = f64>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for x in xs {
        sum += x * x;
        n += 1;
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64).sqrt()
    }
}

/// Geodesic angle between two rotations, rad, in [0, pi].
pub fn geodesic_angle(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    a.angle_to(b)
}

/// RMS of `|p - p_ref|` over paired samples.
pub fn position_rms(measured: &[Vector3<f64>], reference: &[Vector3<f64>]) -> f64 {
    rms(measured.iter().zip(reference).map(|(m, r)| (m - r).norm()))
}

/// RMS of the geodesic angle between measured and reference rotations.
pub fn orientation_rms(measured: &[UnitQuaternion<f64>], reference: &[UnitQuaternion<f64>]) -> f64 {
    rms(measured.iter().zip(reference).map(|(m, r)| geodesic_angle(m, r)))
}

/// Whether and when the object was dropped: a hand without contact for longer than
/// `max_gap` (50 ms), or the object below its start height by more than `max_fall` (10 cm).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DropReport {
    pub dropped: bool,
    /// First time the drop condition held, s.
    pub at: Option<f64>,
    pub reason: Option<String>,
    /// Longest contact gap of any hand, s.
    pub longest_gap: f64,
    /// Largest fall below the start height, m.
    pub largest_fall: f64,
}

/// Drop detection sample by sample (see [`detect_drop`]).
#[derive(Debug, Clone)]
pub struct DropDetector {
    z0: f64,
    max_gap: f64,
    max_fall: f64,
    /// Per hand, since when it has been without contact.
    lost_since: Vec<Option<f64>>,
    report: DropReport,
}

impl DropDetector {
    /// `hands` hands; `z0` the object's start height.
    pub fn new(z0: f64, hands: usize, max_gap: f64, max_fall: f64) -> DropDetector {
        DropDetector {
            z0,
            max_gap,
            max_fall,
            lost_since: vec![None; hands],
            report: DropReport {
                dropped: false,
                at: None,
                reason: None,
                longest_gap: 0.0,
                largest_fall: 0.0,
            },
        }
    }

    /// The sample at `t`: the object at height `z`, each hand's contact.
    pub fn add(&mut self, t: f64, z: f64, contact: &[bool]) {
        let report = &mut self.report;
        let fall = self.z0 - z;
        report.largest_fall = report.largest_fall.max(fall);
        if fall > self.max_fall && !report.dropped {
            report.dropped = true;
            report.at = Some(t);
            report.reason = Some(format!("object {fall:.3} m below its start height"));
        }
        for (h, lost) in self.lost_since.iter_mut().enumerate() {
            let touching = contact.get(h).copied().unwrap_or(false);
            match (touching, *lost) {
                (true, _) => *lost = None,
                (false, None) => *lost = Some(t),
                (false, Some(t0)) => {
                    let gap = t - t0;
                    report.longest_gap = report.longest_gap.max(gap);
                    if gap > self.max_gap && !report.dropped {
                        report.dropped = true;
                        report.at = Some(t);
                        report.reason =
                            Some(format!("hand {h} without contact for {:.0} ms", gap * 1e3));
                    }
                }
            }
        }
    }

    pub fn report(&self) -> DropReport {
        self.report.clone()
    }
}

/// Drop detection over samples `(t, object z, per-hand contact flags)`; `z0` is the object's
/// start height (the fall is measured from it, not from the first sample).
pub fn detect_drop(
    times: &[f64],
    object_z: &[f64],
    z0: f64,
    hand_contact: &[Vec<bool>],
    max_gap: f64,
    max_fall: f64,
) -> DropReport {
    let hands = hand_contact.first().map_or(0, Vec::len);
    let mut d = DropDetector::new(z0, hands, max_gap, max_fall);
    for (k, &t) in times.iter().enumerate() {
        d.add(t, object_z[k], &hand_contact[k]);
    }
    d.report()
}

/// Slip: the largest displacement of a contact point on the object surface from where it
/// was at the first sample (points expressed in the object frame).
pub fn slip(points_in_object: &[Vector3<f64>]) -> f64 {
    let Some(p0) = points_in_object.first() else { return 0.0 };
    points_in_object.iter().map(|p| (p - p0).norm()).fold(0.0, f64::max)
}

/// RMS of each joint's torque over the samples (each sample one vector of joint torques).
pub fn torque_rms(samples: &[Vec<f64>]) -> Vec<f64> {
    let n = samples.first().map_or(0, Vec::len);
    (0..n).map(|j| rms(samples.iter().map(|s| s.get(j).copied().unwrap_or(0.0)))).collect()
}

/// Distribution of a series.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Percentiles {
    pub count: usize,
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
    pub mean: f64,
}

/// Nearest-rank percentiles.
pub fn percentiles(xs: &[f64]) -> Percentiles {
    let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(|a, b| a.total_cmp(b));
    let at = |p: f64| {
        if v.is_empty() {
            0.0
        } else {
            v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1]
        }
    };
    Percentiles {
        count: v.len(),
        p50: at(0.5),
        p90: at(0.9),
        p99: at(0.99),
        max: v.last().copied().unwrap_or(0.0),
        mean: if v.is_empty() { 0.0 } else { v.iter().sum::<f64>() / v.len() as f64 },
    }
}

/// Values kept exactly up to this many; past it a [`Quantiles`] keeps a histogram.
pub const EXACT_QUANTILES: usize = 1 << 16;
/// The histogram's buckets: each this much wider than the one below (a relative error of at
/// most half of it, 0.5 %).
const BUCKET_RATIO: f64 = 1.01;
/// The histogram's smallest bucket; values at or below it count in it.
const BUCKET_FLOOR: f64 = 1e-6;

/// A distribution taken one value at a time in bounded memory: the values themselves while
/// they are at most [`EXACT_QUANTILES`] (nearest-rank percentiles as [`percentiles`] gives),
/// then a histogram of log-spaced buckets (percentiles within 0.5 %; count, mean and max stay
/// exact). Non-finite values are left out, as [`percentiles`] leaves them.
#[derive(Debug, Clone, Default)]
pub struct Quantiles {
    exact: Vec<f64>,
    /// Counts per bucket once the values overflowed (empty before).
    buckets: Vec<u64>,
    count: usize,
    sum: f64,
    max: f64,
}

impl Quantiles {
    pub fn add(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.max = if self.count == 0 { x } else { self.max.max(x) };
        self.count += 1;
        self.sum += x;
        if self.buckets.is_empty() {
            self.exact.push(x);
            if self.exact.len() > EXACT_QUANTILES {
                for v in std::mem::take(&mut self.exact) {
                    self.bucket(v);
                }
            }
        } else {
            self.bucket(x);
        }
    }

    fn bucket(&mut self, x: f64) {
        let k = if x <= BUCKET_FLOOR {
            0
        } else {
            1 + ((x / BUCKET_FLOOR).ln() / BUCKET_RATIO.ln()) as usize
        };
        if self.buckets.len() <= k {
            self.buckets.resize(k + 1, 0);
        }
        self.buckets[k] += 1;
    }

    /// The value a bucket stands for: its geometric middle (the floor for the first).
    fn bucket_value(k: usize) -> f64 {
        match k {
            0 => BUCKET_FLOOR,
            _ => BUCKET_FLOOR * BUCKET_RATIO.powf(k as f64 - 0.5),
        }
    }

    /// Nearest-rank percentiles of the values taken.
    pub fn percentiles(&self) -> Percentiles {
        if self.buckets.is_empty() {
            return percentiles(&self.exact);
        }
        let n = self.count;
        let at = |p: f64| {
            let rank = ((p * n as f64).ceil() as usize).clamp(1, n) as u64;
            let mut seen = 0;
            for (k, c) in self.buckets.iter().enumerate() {
                seen += c;
                if seen >= rank {
                    return Self::bucket_value(k).min(self.max);
                }
            }
            self.max
        };
        Percentiles {
            count: n,
            p50: at(0.5),
            p90: at(0.9),
            p99: at(0.99),
            max: self.max,
            mean: self.sum / n as f64,
        }
    }
}

/// RMS and largest value of a series taken one value at a time.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunningRms {
    sum_sq: f64,
    n: u64,
    max: f64,
}

impl RunningRms {
    pub fn add(&mut self, x: f64) {
        self.sum_sq += x * x;
        self.n += 1;
        self.max = self.max.max(x);
    }

    /// The RMS (0 for no value).
    pub fn rms(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            (self.sum_sq / self.n as f64).sqrt()
        }
    }

    /// The largest value (0 for none; the series are errors and forces, at least 0).
    pub fn max(&self) -> f64 {
        self.max
    }
}

/// Tracking error `after` seconds after `push_end`: the largest error from then until the end
/// of `window` (or the end of the series).
pub fn recovery_error(
    times: &[f64],
    errors: &[f64],
    push_end: f64,
    after: f64,
    window: f64,
) -> Option<f64> {
    let from = push_end + after;
    let to = from + window;
    times
        .iter()
        .zip(errors)
        .filter(|(t, _)| **t >= from && **t <= to)
        .map(|(_, e)| *e)
        .reduce(f64::max)
}

/// How much a long run's error grew: its RMS over the last `window` s less its RMS over the
/// first `window` s (`times` in s, one per error), when the run is at least three windows long.
pub fn growth(times: &[f64], errors: &[f64], window: f64) -> Option<f64> {
    let (first, last) = (*times.first()?, *times.last()?);
    if last - first < 3.0 * window {
        return None;
    }
    let over = |from: f64, to: f64| {
        rms(times.iter().zip(errors).filter(|(t, _)| **t >= from && **t < to).map(|(_, e)| *e))
    };
    Some(over(last - window, f64::INFINITY) - over(first, first + window))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn growth_compares_the_last_window_with_the_first_in_long_runs_only() {
        let times: Vec<f64> = (0..=900).map(|k| f64::from(k) * 0.1).collect();
        // Linear from 0 to 9 over 90 s.
        let errors: Vec<f64> = times.iter().map(|t| t * 0.1).collect();
        let rms_of = |a: f64, b: f64| {
            let xs: Vec<f64> = times
                .iter()
                .zip(&errors)
                .filter(|(t, _)| **t >= a && **t < b)
                .map(|(_, e)| *e)
                .collect();
            (xs.iter().map(|x| x * x).sum::<f64>() / xs.len() as f64).sqrt()
        };
        let g = growth(&times, &errors, 30.0).expect("a run of three windows");
        assert!((g - (rms_of(60.0, 91.0) - rms_of(0.0, 30.0))).abs() < 1e-12, "{g}");
        assert!(g > 5.0);
        let flat = vec![1e-3; times.len()];
        assert!(growth(&times, &flat, 30.0).expect("long").abs() < 1e-15);
        assert_eq!(growth(&times[..800], &errors[..800], 30.0), None, "under three windows");
    }

    #[test]
    fn rms_and_percentiles_of_known_series() {
        assert!((rms([3.0, 4.0]) - (12.5f64).sqrt()).abs() < 1e-15);
        assert_eq!(rms(std::iter::empty()), 0.0);
        let xs: Vec<f64> = (1..=100).map(f64::from).collect();
        let p = percentiles(&xs);
        assert_eq!((p.p50, p.p90, p.p99, p.max), (50.0, 90.0, 99.0, 100.0));
        assert!((p.mean - 50.5).abs() < 1e-12);
    }

    #[test]
    fn quantiles_are_exact_while_small_and_within_half_a_percent_after() {
        let mut q = Quantiles::default();
        for x in 1..=100 {
            q.add(f64::from(x));
        }
        q.add(f64::NAN);
        assert_eq!(q.percentiles(), percentiles(&(1..=100).map(f64::from).collect::<Vec<_>>()));
        // Past the exact store: a known distribution (uniform on 1..=200_000 us).
        let mut q = Quantiles::default();
        let xs: Vec<f64> = (1..=200_000).map(f64::from).collect();
        for x in xs.iter().rev() {
            q.add(*x);
        }
        let (got, want) = (q.percentiles(), percentiles(&xs));
        assert_eq!((got.count, got.max), (want.count, want.max));
        assert!((got.mean - want.mean).abs() < 1e-6 * want.mean);
        for (g, w) in [(got.p50, want.p50), (got.p90, want.p90), (got.p99, want.p99)] {
            assert!((g - w).abs() <= 0.005 * w + 1.0, "{g} against {w}");
        }
        let mut r = RunningRms::default();
        [3.0, 4.0].into_iter().for_each(|x| r.add(x));
        assert!((r.rms() - rms([3.0, 4.0])).abs() < 1e-15 && r.max() == 4.0);
    }

    #[test]
    fn orientation_error_is_the_geodesic_angle() {
        let a = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3);
        let b = a * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.05);
        assert!((geodesic_angle(&a, &b) - 0.05).abs() < 1e-12);
        let e = orientation_rms(&[a, b], &[a, a]);
        assert!((e - 0.05 / 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn drop_needs_a_long_gap_or_a_fall() {
        let t: Vec<f64> = (0..200).map(|k| k as f64 * 0.001).collect();
        let z = vec![0.6; 200];
        // A 40 ms gap of hand 1: not a drop.
        let mut c: Vec<Vec<bool>> = (0..200).map(|_| vec![true, true]).collect();
        for flags in c.iter_mut().take(90).skip(50) {
            flags[1] = false;
        }
        let r = detect_drop(&t, &z, 0.6, &c, 0.05, 0.1);
        assert!(!r.dropped && (r.longest_gap - 0.039).abs() < 1e-9, "{r:?}");
        // 60 ms: a drop, at the time the gap passed 50 ms.
        for flags in c.iter_mut().take(110).skip(50) {
            flags[1] = false;
        }
        let r = detect_drop(&t, &z, 0.6, &c, 0.05, 0.1);
        assert!(r.dropped && (r.at.unwrap() - 0.101).abs() < 1e-9, "{r:?}");
        // A fall of 11 cm with both hands on: a drop.
        let c: Vec<Vec<bool>> = (0..200).map(|_| vec![true, true]).collect();
        let z: Vec<f64> = (0..200).map(|k| 0.6 - k as f64 * 0.001).collect();
        let r = detect_drop(&t, &z, 0.6, &c, 0.05, 0.1);
        assert!(r.dropped && r.reason.unwrap().contains("below"));
        // Already 11 cm low at the first sample (fell while settling): a drop too.
        let z = vec![0.49; 200];
        assert!(detect_drop(&t, &z, 0.6, &c, 0.05, 0.1).dropped);
        assert!(!detect_drop(&t, &z, 0.5, &c, 0.05, 0.1).dropped);
    }

    #[test]
    fn slip_torque_rms_and_recovery() {
        let pts = vec![
            Vector3::new(0.3, 0.0, 0.0),
            Vector3::new(0.3, 0.003, 0.004),
            Vector3::new(0.3, 0.001, 0.0),
        ];
        assert!((slip(&pts) - 0.005).abs() < 1e-15);
        let tau = vec![vec![1.0, -2.0], vec![-1.0, 2.0]];
        assert_eq!(torque_rms(&tau), vec![1.0, 2.0]);
        let t = [0.0, 1.0, 2.0, 3.0, 4.0];
        let e = [0.0, 0.5, 0.2, 0.004, 0.001];
        assert_eq!(recovery_error(&t, &e, 1.0, 2.0, 10.0), Some(0.004));
        assert_eq!(recovery_error(&t, &e, 10.0, 2.0, 1.0), None);
    }
}
