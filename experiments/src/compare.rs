//! Controllers side by side (experiment S3, the paper's "Controller Comparison") and the
//! motion sweep: the same scenarios run with each controller, one report folder with a table
//! ([`Row`]: tracking, drops, slip, contact forces against their limits, solve times, QP
//! failures), the paper's figure (object Z, desired and every controller; [`crate::compare_plot`])
//! and each run's own report in a sub-folder.
//!
//! * [`compare`]: scenarios x controllers (`team compare`).
//! * [`sweep`]: one scenario's motion amplitudes (or speeds) scaled by each factor x
//!   controllers, and where each controller stops meeting the acceptance bounds
//!   (`team sweep`).

use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use thiserror::Error;

use evaluation::evaluate::{self, Evaluation};
use evaluation::records::Records;
use evaluation::report::{self, ReportError, TimeSeries};
use launch::run::{self, RunOptions};
use planner::reference::OffsetMotion;
use scenario::file::Scenario;
use scenario::plan::{self, Plan};

/// What stops a comparison (a run that fails is a row with its error, not this).
#[derive(Debug, Error)]
pub enum CompareError {
    #[error(transparent)]
    Scenario(#[from] scenario::file::ScenarioError),
    #[error(transparent)]
    Report(#[from] ReportError),
    #[error("cannot write {path}: {reason}")]
    Io { path: String, reason: String },
}

/// One run of the table.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Row {
    pub scenario: String,
    pub controller: String,
    /// Motion amplitude factor (1 = the scenario's own).
    pub scale: f64,
    pub object_position_rms_mm: f64,
    pub object_orientation_rms_deg: f64,
    /// Worst torso.
    pub torso_position_rms_mm: f64,
    pub dropped: bool,
    pub drop_reason: Option<String>,
    /// Worst palm.
    pub slip_mm: f64,
    /// Measured (ground truth) least palm normal force over the run, and its limit (the
    /// scenario's least squeeze).
    pub min_hand_force_n: f64,
    pub hand_force_limit_n: f64,
    /// Measured largest tangential / normal force of a palm, and the friction coefficient.
    pub hand_friction_use: f64,
    pub friction: f64,
    pub qp_solve_p50_us: f64,
    pub qp_solve_p99_us: f64,
    pub tick_p50_us: f64,
    pub tick_p99_us: f64,
    /// Ticks whose QP was not solved (any status but Solved / AlmostSolved), and fallbacks.
    pub qp_failures: u64,
    pub fallbacks: Option<u64>,
    pub passed: bool,
    /// The run did not complete: why.
    pub error: Option<String>,
}

/// A finished run: its row and the object's Z (desired, measured) for the figure.
struct Finished {
    row: Row,
    series: Option<TimeSeries>,
}

/// What a sweep scales.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scaling {
    /// Every motion amplitude (sinusoid amplitudes, circle radii).
    Amplitude,
    /// Every motion's speed (frequencies; a sequence's segments are `k` times shorter).
    Speed,
}

/// Scale `m` by `k` (see [`Scaling`]).
pub fn scale_motion(m: &mut OffsetMotion, k: f64, what: Scaling) {
    match (m, what) {
        (OffsetMotion::Hold, _) => {}
        (OffsetMotion::Sinusoid { amplitude, .. }, Scaling::Amplitude) => {
            amplitude.iter_mut().for_each(|a| *a *= k)
        }
        (OffsetMotion::Sinusoid { frequency, .. }, Scaling::Speed) => {
            frequency.iter_mut().for_each(|f| *f *= k)
        }
        (OffsetMotion::Circle { radius, .. }, Scaling::Amplitude) => *radius *= k,
        (OffsetMotion::Circle { frequency, .. }, Scaling::Speed) => *frequency *= k,
        (OffsetMotion::Sequence { segments }, _) => {
            for seg in segments {
                scale_motion(&mut seg.motion, k, what);
                if what == Scaling::Speed {
                    seg.duration /= k;
                    seg.ramp /= k;
                }
            }
        }
    }
}

fn scaled(mut s: Scenario, k: f64, what: Scaling) -> Scenario {
    scale_motion(&mut s.references.object.position, k, what);
    scale_motion(&mut s.references.object.orientation, k, what);
    for t in &mut s.references.torsos {
        scale_motion(&mut t.motion.position, k, what);
        scale_motion(&mut t.motion.orientation, k, what);
    }
    s
}

/// Measured palm forces: the least normal force and the largest tangential / normal ratio.
fn hand_forces(records: &Records, robots: &[String]) -> (f64, f64) {
    let (mut min_n, mut max_ratio) = (f64::INFINITY, 0.0f64);
    for g in records.truth.iter().filter(|g| g.object.is_some()) {
        for r in robots {
            let Some(palm) = g.hands.iter().find(|b| &b.name == r) else { continue };
            let q = palm.pose.orientation;
            let n =
                UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]))
                    * Vector3::z();
            let f: Vector3<f64> = g
                .hand_contacts
                .iter()
                .filter(|c| &c.robot == r)
                .map(|c| Vector3::new(c.wrench[0], c.wrench[1], c.wrench[2]))
                .sum();
            let f_n = n.dot(&f);
            min_n = min_n.min(f_n);
            if f_n > 1e-6 {
                max_ratio = max_ratio.max((f - f_n * n).norm() / f_n);
            }
        }
    }
    (if min_n.is_finite() { min_n } else { 0.0 }, max_ratio)
}

fn row_of(plan: &Plan, eval: &Evaluation, records: &Records, scale: f64) -> Row {
    let m = &eval.metrics;
    let robots: Vec<String> = plan.robots.iter().map(|r| r.id.clone()).collect();
    let (min_hand, friction_use) = hand_forces(records, &robots);
    let failures = records
        .diagnostics
        .iter()
        .filter(|d| {
            !matches!(d.qp_status, protocol::QpStatus::Solved | protocol::QpStatus::AlmostSolved)
        })
        .count() as u64;
    Row {
        scenario: plan.scenario.name.clone(),
        controller: plan.controller.kind().to_string(),
        scale,
        object_position_rms_mm: m.object.position_rms_m * 1e3,
        object_orientation_rms_deg: m.object.orientation_rms_deg,
        torso_position_rms_mm: m
            .torsos
            .values()
            .map(|t| t.position_rms_m * 1e3)
            .fold(0.0, f64::max),
        dropped: m.drop.dropped,
        drop_reason: m.drop.reason.clone(),
        slip_mm: m.slip_m.values().copied().fold(0.0, f64::max) * 1e3,
        min_hand_force_n: min_hand,
        hand_force_limit_n: plan.scenario.min_hand_force,
        hand_friction_use: friction_use,
        friction: plan.scenario.object.friction,
        qp_solve_p50_us: m.qp_solve_us.p50,
        qp_solve_p99_us: m.qp_solve_us.p99,
        tick_p50_us: m.controller_tick_us.p50,
        tick_p99_us: m.controller_tick_us.p99,
        qp_failures: failures,
        fallbacks: m.coordinator_fallbacks,
        passed: m.passed,
        error: None,
    }
}

/// Run `s` (already with its controller) into `dir`: its own report and its row.
fn run_one(s: Scenario, scale: f64, root: &Path, dir: &Path, progress: bool) -> Finished {
    let failed = |why: String| Finished {
        row: Row {
            scenario: s.name.clone(),
            controller: s.controller.clone(),
            scale,
            error: Some(why),
            ..Row::default()
        },
        series: None,
    };
    if let Err(e) = std::fs::create_dir_all(dir) {
        return failed(format!("creating {}: {e}", dir.display()));
    }
    let plan = match plan::plan(&s, root) {
        Ok(p) => p,
        Err(e) => return failed(format!("plan: {e}")),
    };
    let records = match run::run(
        &plan,
        &RunOptions { distributed: false, hosts: false, progress, loss: Vec::new() },
        dir,
    ) {
        Ok(r) => r,
        Err(e) => return failed(format!("run: {e}")),
    };
    let eval = evaluate::evaluate(&plan, &records, "embedded");
    if let Err(e) = evaluate::write_report(&plan, &eval, dir)
        .and_then(|_| evaluation::plots::write_all(&plan, &eval, &records, dir))
    {
        return failed(format!("report: {e}"));
    }
    eprint!("{}", evaluate::summary(&eval.metrics, dir));
    Finished { row: row_of(&plan, &eval, &records, scale), series: Some(eval.series) }
}

fn stem(p: &Path) -> String {
    p.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "scenario".into())
}

/// Every scenario with every controller (`sets` apply to all), into `out`: one sub-folder per
/// run (`<scenario>-<controller>`, its report with figures and report.html, no recording),
/// `<scenario>_object_z.svg` / `.png` per scenario, and
/// `comparison.md` / `comparison.json` with the table.
pub fn compare(
    files: &[PathBuf],
    controllers: &[String],
    sets: &[String],
    out: &Path,
    root: &Path,
    progress: bool,
) -> Result<Vec<Row>, CompareError> {
    let mut rows = Vec::new();
    for file in files {
        let mut runs = Vec::new();
        for c in controllers {
            let mut all = sets.to_vec();
            all.push(format!("controller={c}"));
            let s = Scenario::load(file, &all)?;
            eprintln!("{}: with {c}...", s.name);
            let f = run_one(s, 1.0, root, &out.join(format!("{}-{c}", stem(file))), progress);
            rows.push(f.row.clone());
            runs.push((c.clone(), f.series));
        }
        crate::compare_plot::object_z(
            &runs,
            &stem(file),
            &out.join(format!("{}_object_z.svg", stem(file))),
        )?;
    }
    write_table(&rows, out, "comparison")?;
    Ok(rows)
}

/// Per controller, the largest motion factor at which it met every bound (`None`: not even the
/// first).
pub type Limits = Vec<(String, Option<f64>)>;

/// A sweep's report folder when none is given: `reports/sweep-<file name without extension>`.
pub fn default_sweep_dir(file: &Path) -> PathBuf {
    PathBuf::from("reports").join(format!(
        "sweep-{}",
        file.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default()
    ))
}

/// One line per controller of a sweep's [`Limits`]: the largest factor of `scales` at which it
/// met every bound, or that it missed one already at the first.
pub fn limits_summary(limits: &Limits, what: Scaling, scales: &[f64]) -> String {
    let mut s = String::new();
    for (c, k) in limits {
        match k {
            Some(k) => s.push_str(&format!("{c}: meets every bound up to motion {what:?} x {k}\n")),
            None => s.push_str(&format!(
                "{c}: misses a bound already at motion {what:?} x {}\n",
                scales.first().copied().unwrap_or(0.0)
            )),
        }
    }
    s
}

/// `file` with its motion amplitudes (or speeds) scaled by each of `scales`, with every
/// controller, into `out` (`sweep.md` / `sweep.json` and one sub-folder per run). Returns the
/// rows and, per controller, the largest scale at which it met every bound before its first
/// failure.
pub fn sweep(
    file: &Path,
    controllers: &[String],
    (scales, what): (&[f64], Scaling),
    sets: &[String],
    out: &Path,
    root: &Path,
    progress: bool,
) -> Result<(Vec<Row>, Limits), CompareError> {
    let mut rows = Vec::new();
    let mut limits = Vec::new();
    for c in controllers {
        let mut all = sets.to_vec();
        all.push(format!("controller={c}"));
        let base = Scenario::load(file, &all)?;
        let mut last_pass = None;
        for &k in scales {
            eprintln!("{}: {c}, motion {what:?} x {k}...", base.name);
            let f = run_one(
                scaled(base.clone(), k, what),
                k,
                root,
                &out.join(format!("{}-{c}-x{k}", stem(file))),
                progress,
            );
            let passed = f.row.passed;
            rows.push(f.row);
            if !passed {
                break;
            }
            last_pass = Some(k);
        }
        limits.push((c.clone(), last_pass));
    }
    write_table(&rows, out, "sweep")?;
    Ok((rows, limits))
}

/// The table as Markdown (what the README quotes).
pub fn markdown(rows: &[Row]) -> String {
    let mut s = String::from(
        "| scenario | controller | motion x | object pos RMS [mm] | object ori RMS [deg] \
         | worst torso pos RMS [mm] | dropped | worst slip [mm] | least squeeze [N] (limit) \
         | friction use (mu) | QP solve p50 / p99 [us] | tick p50 / p99 [us] | QP failures \
         | fallbacks | S4 bounds met |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        if let Some(e) = &r.error {
            s.push_str(&format!(
                "| {} | {} | {} | run failed: {} |||||||||||\n",
                r.scenario,
                r.controller,
                r.scale,
                e.replace('|', "/")
            ));
            continue;
        }
        s.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.3} | {:.2} | {} | {:.2} | {:.1} ({:.0}) | {:.2} ({:.2}) \
             | {:.0} / {:.0} | {:.0} / {:.0} | {} | {} | {} |\n",
            r.scenario,
            r.controller,
            r.scale,
            r.object_position_rms_mm,
            r.object_orientation_rms_deg,
            r.torso_position_rms_mm,
            if r.dropped { r.drop_reason.as_deref().unwrap_or("yes") } else { "no" },
            r.slip_mm,
            r.min_hand_force_n,
            r.hand_force_limit_n,
            r.hand_friction_use,
            r.friction,
            r.qp_solve_p50_us,
            r.qp_solve_p99_us,
            r.tick_p50_us,
            r.tick_p99_us,
            r.qp_failures,
            r.fallbacks.map_or("-".to_string(), |f| f.to_string()),
            if r.passed { "yes" } else { "NO" },
        ));
    }
    s
}

fn write_table(rows: &[Row], out: &Path, name: &str) -> Result<(), CompareError> {
    let md = out.join(format!("{name}.md"));
    std::fs::write(&md, markdown(rows))
        .map_err(|e| CompareError::Io { path: md.display().to_string(), reason: e.to_string() })?;
    report::write_json(&rows, &out.join(format!("{name}.json")))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::reference::{Plane, Segment};

    #[test]
    fn a_sweep_scales_amplitudes_or_speeds_and_nothing_else() {
        let sin = OffsetMotion::Sinusoid {
            amplitude: [0.03, 0.0, 0.02],
            frequency: [0.2, 0.0, 0.25],
            phase: [0.1, 0.0, 0.0],
        };
        let circle =
            OffsetMotion::Circle { radius: 0.04, frequency: 0.2, plane: Plane::Xz, phase: 0.0 };
        let seq = OffsetMotion::Sequence {
            segments: vec![Segment { duration: 2.0, motion: sin.clone(), ramp: 0.5 }],
        };
        let mut m = sin.clone();
        scale_motion(&mut m, 2.0, Scaling::Amplitude);
        assert_eq!(
            m,
            OffsetMotion::Sinusoid {
                amplitude: [0.06, 0.0, 0.04],
                frequency: [0.2, 0.0, 0.25],
                phase: [0.1, 0.0, 0.0]
            }
        );
        let mut m = sin.clone();
        scale_motion(&mut m, 2.0, Scaling::Speed);
        assert_eq!(
            m,
            OffsetMotion::Sinusoid {
                amplitude: [0.03, 0.0, 0.02],
                frequency: [0.4, 0.0, 0.5],
                phase: [0.1, 0.0, 0.0]
            }
        );
        let mut m = circle;
        scale_motion(&mut m, 3.0, Scaling::Amplitude);
        assert!(matches!(
            m,
            OffsetMotion::Circle { radius, frequency, .. }
                if (radius - 0.12).abs() < 1e-15 && frequency == 0.2
        ));
        let mut m = seq;
        scale_motion(&mut m, 2.0, Scaling::Speed);
        let OffsetMotion::Sequence { segments } = m else { panic!("a sequence") };
        assert_eq!((segments[0].duration, segments[0].ramp), (1.0, 0.25));
        assert!(matches!(
            segments[0].motion,
            OffsetMotion::Sinusoid { frequency, .. } if frequency == [0.4, 0.0, 0.5]
        ));
        let mut hold = OffsetMotion::Hold;
        scale_motion(&mut hold, 5.0, Scaling::Speed);
        assert_eq!(hold, OffsetMotion::Hold);
    }

    #[test]
    fn the_table_names_a_failed_run_and_marks_missed_bounds() {
        let ok = Row {
            scenario: "S".into(),
            controller: "mqp".into(),
            scale: 1.0,
            passed: true,
            fallbacks: Some(0),
            ..Row::default()
        };
        let bad = Row {
            controller: "pidc".into(),
            scale: 4.0,
            dropped: true,
            drop_reason: Some("hand 1 without contact for 50 ms".into()),
            ..ok.clone()
        };
        let bad = Row { passed: false, ..bad };
        let failed = Row { error: Some("run: no torques | from r2".into()), ..ok.clone() };
        let md = markdown(&[ok, bad, failed]);
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(lines.len(), 5, "{md}");
        assert!(lines[2].starts_with("| S | mqp | 1 |") && lines[2].ends_with("| yes |"), "{md}");
        assert!(
            lines[3].contains("hand 1 without contact for 50 ms") && lines[3].ends_with("| NO |"),
            "{md}"
        );
        assert!(lines[4].contains("run failed: run: no torques / from r2"), "{md}");
    }

    #[test]
    fn a_sweep_says_up_to_which_scale_each_controller_met_the_bounds() {
        let limits: Limits = vec![("pidc".into(), Some(1.5)), ("mqp".into(), None)];
        let s = limits_summary(&limits, Scaling::Speed, &[0.5, 1.0, 1.5]);
        assert_eq!(
            s,
            concat!(
                "pidc: meets every bound up to motion Speed x 1.5\n",
                "mqp: misses a bound already at motion Speed x 0.5\n"
            )
        );
        assert_eq!(
            default_sweep_dir(Path::new("scenarios/s1_torso_and_object.toml")),
            Path::new("reports/sweep-s1_torso_and_object")
        );
    }
}
