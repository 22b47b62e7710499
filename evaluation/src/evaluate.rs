//! From a run's records to the report: every measure of success (`metrics.json`; see
//! `docs/scenarios.md`), the time series (`timeseries.csv`, `torques.csv`) and the
//! acceptance checks of the team demo. Measured values come from the ground truth only. A run
//! that ended in an error is measured over the ticks it saw, the error named in the report
//! ([`evaluate_failed`]).

use std::collections::BTreeMap;
use std::path::Path;

use protocol::GroundTruth;
use robot_agent::delay::TeamDelay;
use serde::Serialize;

use crate::metrics::{DropReport, Percentiles, RunningRms};
use crate::records::Records;
use crate::report::{self, ReportError, TimeSeries};
use crate::tally::{RunView, Tally};
use scenario::Plan;

/// Bounds of the acceptance checks of the team demo.
pub const MAX_SLIP: f64 = 0.005;
pub const MAX_OBJECT_POSITION_RMS: f64 = 0.01;
pub const MAX_OBJECT_ORIENTATION_RMS_DEG: f64 = 2.0;
pub const MAX_TORSO_POSITION_RMS: f64 = 0.01;
pub const MAX_RECOVERY_ERROR: f64 = 0.01;
/// How much the object's position error may grow from the first [`GROWTH_WINDOW`] of a run to
/// its last (RMS, m), in runs at least three windows long.
pub const MAX_OBJECT_ERROR_GROWTH: f64 = 1e-4;
/// The windows [`MAX_OBJECT_ERROR_GROWTH`] compares, s.
pub const GROWTH_WINDOW: f64 = 30.0;
/// Recovery is judged this long after a push ends, s.
pub const RECOVERY_AFTER: f64 = 2.0;
/// The CSV time series and plots keep at most this many samples per second (the metrics use
/// every tick).
pub const SERIES_HZ: f64 = 25.0;

/// Tracking of one pose task.
#[derive(Debug, Clone, Serialize)]
pub struct Tracking {
    pub position_rms_m: f64,
    pub position_max_m: f64,
    pub orientation_rms_deg: f64,
    pub orientation_max_deg: f64,
}

/// Recovery after one push.
#[derive(Debug, Clone, Serialize)]
pub struct Recovery {
    pub on: String,
    pub push_end_s: f64,
    /// Largest object position error from `push_end + 2 s` until the next push starts (or the
    /// end), m.
    pub object_error_after_m: Option<f64>,
    /// Same for the pushed torso (pushes on a robot).
    pub torso_error_after_m: Option<f64>,
}

/// One acceptance check.
#[derive(Debug, Clone, Serialize)]
pub struct Check {
    pub name: String,
    pub value: f64,
    pub bound: f64,
    pub passed: bool,
}

/// The ticks on which the controller's motion yielded (`TickDiagnostics::motion_yield`): the
/// contact forces could not carry the tasks' full motion, so the object's, then the torsos',
/// gave way before the grasp.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct YieldReport {
    pub ticks: u64,
    pub first_tick: u64,
    pub last_tick: u64,
    /// The least share of its motion the object kept, and on how many ticks it was held still.
    pub least_object_share: f64,
    pub object_still_ticks: u64,
    /// Ticks on which the torsos' motion yielded too (the object held still).
    pub torso_ticks: u64,
}

impl YieldReport {
    /// A tick whose motion yielded by `y`, into `report`.
    pub(crate) fn add(report: &mut Option<YieldReport>, tick: u64, y: &protocol::MotionYield) {
        let r = report.get_or_insert(YieldReport {
            ticks: 0,
            first_tick: tick,
            last_tick: tick,
            least_object_share: 1.0,
            object_still_ticks: 0,
            torso_ticks: 0,
        });
        r.ticks += 1;
        r.last_tick = tick;
        r.least_object_share = r.least_object_share.min(y.object);
        r.object_still_ticks += u64::from(y.object == 0.0);
        r.torso_ticks += u64::from(y.torso < 1.0);
    }

    /// One line of the summary.
    pub fn summary(&self) -> String {
        format!(
            "  motion yielded on {} ticks ({}..{}): the object kept at least {:.0} % of its \
             motion, held still on {} ticks; the torsos yielded on {}\n",
            self.ticks,
            self.first_tick,
            self.last_tick,
            100.0 * self.least_object_share,
            self.object_still_ticks,
            self.torso_ticks
        )
    }
}

/// Everything `metrics.json` holds.
#[derive(Debug, Clone, Serialize)]
pub struct Metrics {
    pub scenario: String,
    pub mode: String,
    /// The error the run ended in (`None`: it ran to its end). A run with one is measured over
    /// the ticks it saw and never passes.
    pub error: Option<String>,
    pub duration_s: f64,
    pub control_hz: f64,
    pub physics_hz: f64,
    /// The team loop's rate (the control rate unless `team_hz` set it lower).
    pub team_hz: f64,
    /// The team's delay, robot ticks (`team_delay_ticks`); with `auto`, the longest any
    /// agent came to.
    pub team_delay_ticks: u64,
    /// Whether the agents set the delay from the latency they measured (`auto`).
    pub team_delay_auto: bool,
    /// The gains the agents sent with their drive commands (`none`, `inertia`).
    pub drive_gains: String,
    pub samples: usize,
    /// Ticks the run saw (ground truth, settling included), of the ticks it planned.
    pub ticks_seen: u64,
    pub ticks_planned: u64,
    pub object: Tracking,
    pub torsos: BTreeMap<String, Tracking>,
    pub drop: DropReport,
    /// Largest displacement of each palm on the object surface, m.
    pub slip_m: BTreeMap<String, f64>,
    /// Mean normal force of each hand on the object, N.
    pub mean_squeeze_n: BTreeMap<String, f64>,
    /// Torque RMS per joint, by robot then joint name, N m.
    pub torque_rms: BTreeMap<String, Vec<(String, f64)>>,
    pub qp_status: BTreeMap<String, u64>,
    /// Ticks whose command did not come from the controller's normal path (the QP's
    /// least-violation fallback, hold orders after a controller error, or free hands after
    /// the controller let go of the object), by what was done.
    pub fallback_ticks: BTreeMap<String, u64>,
    /// The ticks whose motion yielded because the contacts could not carry it (`None`: none).
    pub motion_yield: Option<YieldReport>,
    /// Largest residual of the controller's object-pose fit (its own slip signal), m.
    pub grasp_fit_residual_max_m: f64,
    /// How often the controller re-fitted its grasp model to the measured object, and the
    /// largest distance a hand's contact moved on the object since the grasp closed, m.
    pub grasp_refits: u64,
    pub grasp_slip_since_closed_max_m: f64,
    /// The object's position error RMS over the run's last [`GROWTH_WINDOW`] less over its
    /// first, m (`None` in runs shorter than three windows).
    pub object_error_growth_m: Option<f64>,
    /// Why and at which tick the team let go of the object (the coordinator's note), if it did.
    pub release: Option<String>,
    pub qp_iterations: Percentiles,
    pub qp_solve_us: Percentiles,
    pub controller_tick_us: Percentiles,
    pub coordinator_deadline_misses: Option<u64>,
    /// The control loop of a real-time run (`None` in lockstep): latency, misses, late, lost.
    pub loop_timing: Option<crate::loop_timing::LoopReport>,
    pub coordinator_fallbacks: Option<u64>,
    pub recoveries: Vec<Recovery>,
    /// Steps, stance-foot slides and final torso poses of a walk (`None` without one).
    pub walk: Option<crate::walking::WalkReport>,
    pub settle_wall_s: f64,
    pub run_wall_s: f64,
    pub real_time_factor: f64,
    /// The machine's processors over the run: busy, and taken by the host.
    pub machine: Option<crate::machine::MachineLoad>,
    pub checks: Vec<Check>,
    pub passed: bool,
}

/// The evaluated run.
pub struct Evaluation {
    pub metrics: Metrics,
    pub series: TimeSeries,
    pub torques: TimeSeries,
}

/// Evaluate the records of a run of `plan`.
pub fn evaluate(plan: &Plan, records: &Records, mode: &str) -> Evaluation {
    evaluate_with(plan, records, mode, None)
}

/// Evaluate the records of a run of `plan` that ended in `error` after the ticks it saw: every
/// measure over those ticks (a walk judged up to the last sample, the real-time factor over
/// the scenario time seen), the error in the metrics and as a failed check. It never passes.
pub fn evaluate_failed(plan: &Plan, records: &Records, mode: &str, error: &str) -> Evaluation {
    evaluate_with(plan, records, mode, Some(error))
}

/// [`evaluate`], or [`evaluate_failed`] with an `error`.
fn evaluate_with(plan: &Plan, records: &Records, mode: &str, error: Option<&str>) -> Evaluation {
    let tally = records.tally.finished();
    // A failed run is judged up to its last sample (scenario time; 0 without one).
    let until = error.map(|_| tally.last_time().unwrap_or(0.0));
    let walk = tally.run.refs.walk.as_ref().map(|w| {
        let truth: Vec<&GroundTruth> =
            records.truth.iter().filter(|g| g.object.is_some()).collect();
        crate::walking::evaluate(w, &truth, tally.run.refs.walk_halted_at, until)
    });
    let mut metrics = measures(plan, mode, records, &tally, walk, until);
    metrics.error = error.map(str::to_string);
    metrics.checks = acceptance(&tally.run, &metrics);
    metrics.passed = metrics.checks.iter().all(|c| c.passed);
    let (series, torques) = tally.series();
    Evaluation { metrics, series, torques }
}

/// Every measure of the run (no error, no checks yet), from its tally and records; a run
/// judged `until` a scenario time ended there.
fn measures(
    plan: &Plan,
    mode: &str,
    records: &Records,
    tally: &Tally,
    walk: Option<crate::walking::WalkReport>,
    until: Option<f64>,
) -> Metrics {
    let (run, t, d) = (&tally.run, &tally.truth, &tally.diagnostics);
    let n = t.samples.max(1) as f64;
    let sim = until.unwrap_or_else(|| run.refs.clock.scenario_duration());
    Metrics {
        scenario: plan.scenario.name.clone(),
        mode: mode.to_string(),
        error: None,
        duration_s: plan.scenario.duration,
        control_hz: plan.scenario.control_hz,
        physics_hz: plan.scenario.physics_hz,
        team_hz: plan.scenario.control_hz / plan.scenario.team_every().unwrap_or(1) as f64,
        team_delay_ticks: team_delay_ticks(plan, records),
        team_delay_auto: plan.scenario.team_delay_ticks.adapts(),
        drive_gains: plan.scenario.drive_gains.to_string(),
        samples: t.samples,
        ticks_seen: records.ticks_seen,
        ticks_planned: plan.total_ticks(),
        object: tracking(&t.object_position, &t.object_angle),
        torsos: per_robot(&run.robots, |i| tracking(&t.torso_position[i], &t.torso_angle[i])),
        drop: t.drop_report(),
        slip_m: per_robot(&run.robots, |i| t.slip[i]),
        mean_squeeze_n: per_robot(&run.robots, |i| t.squeeze_sum[i] / n),
        torque_rms: torque_rms(plan, tally),
        qp_status: d.qp_status.clone(),
        fallback_ticks: d.fallback_ticks.clone(),
        motion_yield: d.motion_yield.clone(),
        grasp_fit_residual_max_m: d.grasp_fit_residual_max,
        grasp_refits: d.grasp_refits,
        grasp_slip_since_closed_max_m: d.grasp_slip_since_closed_max,
        object_error_growth_m: t.growth(),
        release: d.release.clone(),
        qp_iterations: d.qp_iterations.percentiles(),
        qp_solve_us: d.qp_solve_us.percentiles(),
        controller_tick_us: d.controller_tick_us.percentiles(),
        coordinator_deadline_misses: records.last_status.as_ref().map(|s| s.deadline_misses),
        loop_timing: tally.loop_timing.report(),
        coordinator_fallbacks: records.last_status.as_ref().map(|s| s.fallbacks),
        recoveries: t.recoveries(),
        walk,
        settle_wall_s: records.settle_wall.as_secs_f64(),
        run_wall_s: records.run_wall.as_secs_f64(),
        real_time_factor: real_time_factor(sim, records.run_wall),
        machine: records.machine,
        checks: Vec::new(),
        passed: false,
    }
}

/// The team's delay, robot ticks: the scenario's, or with `auto` the longest any agent came to.
fn team_delay_ticks(plan: &Plan, records: &Records) -> u64 {
    match plan.scenario.team_delay_ticks {
        TeamDelay::Ticks(d) => d,
        TeamDelay::Auto { .. } => records.agent_delay.values().copied().max().unwrap_or(0),
    }
}

/// One value per robot, by id: `f` of the robot's index.
fn per_robot<T>(robots: &[String], mut f: impl FnMut(usize) -> T) -> BTreeMap<String, T> {
    robots.iter().enumerate().map(|(i, r)| (r.clone(), f(i))).collect()
}

/// Each joint's torque RMS by robot (robots never heard have none).
fn torque_rms(plan: &Plan, tally: &Tally) -> BTreeMap<String, Vec<(String, f64)>> {
    let rms = &tally.torques.rms;
    let joints = |i: usize| plan.robots[i].joints.iter().cloned();
    let named = |i: usize| joints(i).zip(rms[i].iter().map(|a| a.rms())).collect::<Vec<_>>();
    (0..plan.robots.len()).map(|i| (plan.robots[i].id.clone(), named(i))).collect()
}

/// Simulated seconds per wall-clock second of the run (0 without a run).
fn real_time_factor(sim: f64, run_wall: std::time::Duration) -> f64 {
    if run_wall.is_zero() {
        0.0
    } else {
        sim / run_wall.as_secs_f64()
    }
}

/// Tracking of a pose task from its position and orientation errors, rad.
fn tracking(position: &RunningRms, angle: &RunningRms) -> Tracking {
    Tracking {
        position_rms_m: position.rms(),
        position_max_m: position.max(),
        orientation_rms_deg: angle.rms().to_degrees(),
        orientation_max_deg: angle.max().to_degrees(),
    }
}

/// Each palm's slip on the object against [`MAX_SLIP`]. When the controller re-fitted its grasp
/// model to the measured object, the slip it followed is not lost grip: the check is on the
/// slip beyond the farthest any hand's contact was followed (`grasp_slip_since_closed`, the
/// largest over the hands, so a hand that slid less is judged leniently), and a long run must
/// also keep its object error from growing ([`MAX_OBJECT_ERROR_GROWTH`]).
fn palm_slip_checks(run: &RunView, m: &Metrics, check: &mut impl FnMut(String, f64, f64)) {
    let followed = (m.grasp_refits > 0).then_some(m.grasp_slip_since_closed_max_m);
    for (r, s) in m.slip_m.iter().filter(|(r, _)| !run.faulted(r)) {
        match followed {
            None => check(format!("{r} palm slip [m]"), *s, MAX_SLIP),
            Some(f) => check(
                format!("{r} palm slip the grasp model did not follow [m]"),
                (s - f).max(0.0),
                MAX_SLIP,
            ),
        }
    }
    if let Some(g) = m.object_error_growth_m {
        check(
            format!("object error growth, last {GROWTH_WINDOW} s against the first [m]"),
            g,
            MAX_OBJECT_ERROR_GROWTH,
        );
    }
}

/// The acceptance checks of the measures in `m` (robots a fault stops or stalls are not
/// judged).
fn acceptance(run: &RunView, m: &Metrics) -> Vec<Check> {
    let mut checks = Vec::new();
    let mut check = |name: String, value: f64, bound: f64| {
        checks.push(Check { passed: value < bound, name, value, bound })
    };
    if let Some(e) = &m.error {
        check(format!("run ended without an error (1 = it ended in one: {e})"), 1.0, 0.5);
    }
    check("object never dropped (1 = dropped)".into(), if m.drop.dropped { 1.0 } else { 0.0 }, 0.5);
    palm_slip_checks(run, m, &mut check);
    check("object position RMS [m]".into(), m.object.position_rms_m, MAX_OBJECT_POSITION_RMS);
    check(
        "object orientation RMS [deg]".into(),
        m.object.orientation_rms_deg,
        MAX_OBJECT_ORIENTATION_RMS_DEG,
    );
    for (r, t) in m.torsos.iter().filter(|(r, _)| !run.faulted(r)) {
        // A walking torso follows a moving reference: its own bound.
        let i = run.robots.iter().position(|x| x == r);
        let walking = run.refs.walk.as_ref().zip(i).is_some_and(|(w, i)| w.walking[i]);
        let (what, bound) = if walking {
            ("walking torso", crate::walking::MAX_WALKING_TORSO_POSITION_RMS)
        } else {
            ("torso", MAX_TORSO_POSITION_RMS)
        };
        check(format!("{r} {what} position RMS [m]"), t.position_rms_m, bound);
    }
    for (name, value, bound) in m.walk.iter().flat_map(crate::walking::checks) {
        check(name, value, bound);
    }
    for rec in &m.recoveries {
        if let Some(e) = rec.object_error_after_m {
            check(
                format!(
                    "object error {RECOVERY_AFTER} s after the push on {} ending at {:.1} s [m]",
                    rec.on, rec.push_end_s
                ),
                e,
                MAX_RECOVERY_ERROR,
            );
        }
    }
    checks
}

/// Write the report folder's data: `metrics.json`, `timeseries.csv`, `torques.csv` (the
/// figures and `report.html`: [`crate::plots::write_all`]).
pub fn write_report(_plan: &Plan, eval: &Evaluation, dir: &Path) -> Result<(), ReportError> {
    report::write_json(&eval.metrics, &dir.join("metrics.json"))?;
    eval.series.write_csv(&dir.join("timeseries.csv"))?;
    eval.torques.write_csv(&dir.join("torques.csv"))?;
    Ok(())
}

/// A short human summary of the metrics.
pub fn summary(m: &Metrics, dir: &Path) -> String {
    let mut s = summary_heading(m);
    if let Some(e) = &m.error {
        s.push_str(&format!(
            "  RUN FAILED after {} of {} ticks (settling included): {e}; the measures are over \
             the ticks it saw\n",
            m.ticks_seen, m.ticks_planned
        ));
    }
    push_tracking_lines(&mut s, m);
    s.push_str(&format!(
        "  QP: {:?}, solve p50 {:.0} us p99 {:.0} us; controller tick p50 {:.0} us \
         p99 {:.0} us; real-time factor {:.3}\n",
        m.qp_status,
        m.qp_solve_us.p50,
        m.qp_solve_us.p99,
        m.controller_tick_us.p50,
        m.controller_tick_us.p99,
        m.real_time_factor
    ));
    if !m.fallback_ticks.is_empty() {
        s.push_str(&format!("  fallback ticks: {:?}\n", m.fallback_ticks));
    }
    if let Some(y) = &m.motion_yield {
        s.push_str(&y.summary());
    }
    s.push_str(&format!(
        "  controller's grasp-fit residual: max {:.3} mm; {} re-fits to the measured object, \
         a hand moved at most {:.3} mm on it\n",
        m.grasp_fit_residual_max_m * 1e3,
        m.grasp_refits,
        m.grasp_slip_since_closed_max_m * 1e3
    ));
    if let Some(r) = &m.release {
        s.push_str(&format!("  {r}\n"));
    }
    for r in &m.recoveries {
        if let Some(e) = r.object_error_after_m {
            s.push_str(&format!(
                "  push on {} ending at {:.1} s: object error {:.2} mm after {} s\n",
                r.on,
                r.push_end_s,
                e * 1e3,
                RECOVERY_AFTER
            ));
        }
    }
    if let Some(l) = &m.loop_timing {
        s.push_str(&l.summary());
        if let Some(machine) = &m.machine {
            s.push_str(&machine.summary());
        }
    }
    push_acceptance_lines(&mut s, m);
    s.push_str(&format!("  report: {}\n", dir.display()));
    s
}

/// The summary's first line: the scenario, mode, duration and rates.
fn summary_heading(m: &Metrics) -> String {
    let mut team =
        if m.team_hz < m.control_hz { format!(", team {} Hz", m.team_hz) } else { String::new() };
    if m.team_delay_auto {
        team.push_str(&format!(", team delay auto (came to {} ticks)", m.team_delay_ticks));
    } else if m.team_delay_ticks > 0 {
        team.push_str(&format!(", team delay {} ticks", m.team_delay_ticks));
    }
    let gains = if m.drive_gains == "none" {
        String::new()
    } else {
        format!(", drive gains {}", m.drive_gains)
    };
    format!(
        "{} ({} mode, {:.1} s at {} Hz control{team}, {} Hz physics{gains})\n",
        m.scenario, m.mode, m.duration_s, m.control_hz, m.physics_hz
    )
}

/// The summary's lines on the object's and torsos' tracking and the palms' slip.
fn push_tracking_lines(s: &mut String, m: &Metrics) {
    s.push_str(&format!(
        "  object: position RMS {:.2} mm (max {:.2} mm), orientation RMS {:.3} deg \
         (max {:.3} deg), dropped: {}\n",
        m.object.position_rms_m * 1e3,
        m.object.position_max_m * 1e3,
        m.object.orientation_rms_deg,
        m.object.orientation_max_deg,
        if m.drop.dropped { "YES" } else { "no" }
    ));
    for (r, t) in &m.torsos {
        s.push_str(&format!(
            "  torso {r}: position RMS {:.2} mm (max {:.2} mm), orientation RMS {:.3} deg \
             (max {:.2} deg)\n",
            t.position_rms_m * 1e3,
            t.position_max_m * 1e3,
            t.orientation_rms_deg,
            t.orientation_max_deg
        ));
    }
    for (r, x) in &m.slip_m {
        s.push_str(&format!(
            "  palm {r}: slip {:.3} mm, mean squeeze {:.1} N\n",
            x * 1e3,
            m.mean_squeeze_n.get(r).copied().unwrap_or(0.0)
        ));
    }
}

/// The summary's acceptance lines: all passed, or each failed check.
fn push_acceptance_lines(s: &mut String, m: &Metrics) {
    let failed: Vec<&Check> = m.checks.iter().filter(|c| !c.passed).collect();
    if failed.is_empty() {
        s.push_str(&format!("  acceptance: all {} checks passed\n", m.checks.len()));
    } else {
        for c in failed {
            s.push_str(&format!(
                "  acceptance FAILED: {} = {:.4} (bound {})\n",
                c.name, c.value, c.bound
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics;
    use nalgebra::{UnitQuaternion, Vector3};
    use protocol::{BodyTruth, ContactTruth, Header, Pose};
    use scenario::file::Scenario;
    use scenario::plan;

    fn s4_plan() -> Plan {
        s4_plan_of(1.0)
    }

    fn s4_plan_of(duration: f64) -> Plan {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf();
        let s = Scenario::load(
            root.join("scenarios/s4_object_circle.toml"),
            &[format!("duration={duration}"), "settle=0.0".into()],
        )
        .unwrap();
        plan::plan(&s, &root).unwrap()
    }

    fn body(name: &str, p: Vector3<f64>, q: UnitQuaternion<f64>) -> BodyTruth {
        BodyTruth {
            name: name.into(),
            pose: Pose { position: p.into(), orientation: protocol::conventions::quat_to_wxyz(&q) },
            twist: [0.0; 6],
        }
    }

    /// Ground truth that follows the references exactly, palms fixed on the object; `fall(t)`
    /// lowers the object (and the palms with it) and `contact(t)` says whether the hands touch.
    fn records(plan: &Plan, fall: impl Fn(f64) -> f64, contact: impl Fn(f64) -> bool) -> Records {
        records_of(plan, plan.scene.ticks, fall, contact)
    }

    /// [`records`] of the first `ticks` ticks.
    fn records_of(
        plan: &Plan,
        ticks: u64,
        fall: impl Fn(f64) -> f64,
        contact: impl Fn(f64) -> bool,
    ) -> Records {
        let mut rec = Records::new(plan);
        let refs = &plan.references;
        for k in 0..ticks {
            // Settling is 0: the state after tick k's step is at scenario time (k + 1) / rate.
            let t = plan.references.clock.scenario_time(k + 1).expect("no settling");
            let o = refs.object_at(Some(t));
            let mut op = Vector3::from(o.pose.position);
            op.z -= fall(t);
            let oq = protocol::conventions::quat_from_wxyz(o.pose.orientation);
            let mut g = sim_bridge::ground_truth::empty("team");
            g.header = Header::new("team", None, k, 0);
            g.time = t;
            g.object = Some(body("object", op, oq));
            for (i, (id, ..)) in refs.torsos.iter().enumerate() {
                let r = refs.torso_at(i, Some(t));
                g.torsos.push(body(
                    id,
                    Vector3::from(r.pose.position),
                    protocol::conventions::quat_from_wxyz(r.pose.orientation),
                ));
                let side = if i == 0 { -0.3 } else { 0.3 };
                g.hands.push(body(id, op + oq * Vector3::new(side, 0.0, 0.0), oq));
                if contact(t) {
                    g.hand_contacts.push(ContactTruth {
                        robot: id.clone(),
                        body: "hand".into(),
                        position: (op + Vector3::new(side, 0.0, 0.0)).into(),
                        wrench: [-side * 100.0, 0.0, 4.9, 0.0, 0.0, 0.0],
                    });
                }
            }
            rec.keep_truth(g);
        }
        rec.ticks_seen = ticks;
        rec
    }

    #[test]
    fn perfect_tracking_passes_and_a_drop_fails() {
        let plan = s4_plan();
        let good = evaluate(&plan, &records(&plan, |_| 0.0, |_| true), "embedded");
        let m = &good.metrics;
        assert!(m.passed, "{:?}", m.checks);
        assert!(m.object.position_rms_m < 1e-12 && m.object.orientation_rms_deg < 1e-9);
        assert!(m.slip_m.values().all(|s| *s < 1e-12));
        assert!(!m.drop.dropped);
        // The object slides down 15 cm after 0.5 s and the hands lose it for 0.1 s: dropped,
        // slip and position checks fail.
        let bad = evaluate(
            &plan,
            &records(
                &plan,
                |t| if t > 0.5 { (t - 0.5) * 0.5 } else { 0.0 },
                |t| !(0.6..0.7).contains(&t),
            ),
            "embedded",
        );
        let m = &bad.metrics;
        assert!(m.drop.dropped, "{:?}", m.drop);
        assert!(!m.passed);
        let failed: Vec<&str> =
            m.checks.iter().filter(|c| !c.passed).map(|c| c.name.as_str()).collect();
        assert!(
            failed.iter().any(|n| n.contains("dropped"))
                && failed.iter().any(|n| n.contains("object position RMS")),
            "{failed:?}"
        );
        // Writing the report works and gives the plots.
        let dir = std::env::temp_dir().join(format!("evaluate-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_report(&plan, &bad, &dir).unwrap();
        crate::plots::write_all(&plan, &bad, &records(&plan, |_| 0.0, |_| true), &dir).unwrap();
        for f in [
            "metrics.json",
            "timeseries.csv",
            "torques.csv",
            "report.html",
            "object_error.png",
            "object_error.svg",
            "contact_forces.png",
            "torque_rms.svg",
        ] {
            assert!(dir.join(f).exists(), "{f}");
        }
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!(json["passed"], false);
        assert!(json["error"].is_null(), "a run that ran to its end has no error: {json}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A run that ended in an error 40 % into its ticks: measured over the ticks it saw
    /// without a panic, the error in the metrics, the summary, a failed check and the report;
    /// the same ticks with no error pass. With no scenario tick at all (failed while
    /// settling) it still evaluates and reports.
    #[test]
    fn a_run_that_ended_in_an_error_is_measured_over_its_ticks_and_fails() {
        let plan = s4_plan();
        let seen = plan.total_ticks() * 2 / 5;
        let rec = records_of(&plan, seen, |_| 0.0, |_| true);
        let error = "robot r1's agent left the team at tick 400";
        let eval = evaluate_failed(&plan, &rec, "embedded", error);
        let m = &eval.metrics;
        assert_eq!(m.error.as_deref(), Some(error));
        assert!(!m.passed);
        assert_eq!((m.ticks_seen, m.ticks_planned), (seen, plan.total_ticks()));
        assert_eq!(m.samples, seen as usize);
        assert!(m.object.position_rms_m < 1e-12 && !m.drop.dropped, "tracked while it ran");
        let failed: Vec<&Check> = m.checks.iter().filter(|c| !c.passed).collect();
        assert!(failed.len() == 1 && failed[0].name.contains(error), "{failed:?}");
        let dir = std::env::temp_dir().join(format!("evaluate-failed-{}", std::process::id()));
        let text = summary(m, &dir);
        assert!(text.contains("RUN FAILED") && text.contains(error), "{text}");
        assert!(text.contains(&format!("after {seen} of {} ticks", plan.total_ticks())), "{text}");
        let completed = evaluate(&plan, &rec, "embedded").metrics;
        assert!(completed.passed && completed.error.is_none(), "{:?}", completed.checks);

        std::fs::create_dir_all(&dir).unwrap();
        write_report(&plan, &eval, &dir).unwrap();
        crate::plots::write_all(&plan, &eval, &rec, &dir).unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!((json["error"].as_str(), json["passed"].as_bool()), (Some(error), Some(false)));
        assert_eq!(json["ticks_seen"].as_u64(), Some(seen));
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        assert!(html.contains("ended in an error") && html.contains("agent left the team"));

        let mut nothing = Records::new(&plan);
        nothing.ticks_seen = 3;
        let empty = evaluate_failed(&plan, &nothing, "embedded", error);
        let m = &empty.metrics;
        assert!(!m.passed && m.samples == 0 && m.real_time_factor == 0.0, "{m:?}");
        assert!(m.object.position_rms_m == 0.0 && !m.drop.dropped);
        write_report(&plan, &empty, &dir).unwrap();
        crate::plots::write_all(&plan, &empty, &nothing, &dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A run far longer than the trace and the series hold: the trace and the series stay
    /// within their bounds, and the measures are those of every tick (against the analytic
    /// values of a constant offset that starts halfway, and the batch functions).
    #[test]
    fn a_long_run_is_measured_over_every_tick_in_bounded_memory() {
        let plan = s4_plan_of(200.0);
        let rec = records(&plan, |t| if t >= 100.0 { 1e-3 } else { 0.0 }, |_| true);
        let ticks = plan.scene.ticks as usize;
        let cap = crate::records::TRACE_ROBOT_SAMPLES / plan.robots.len();
        assert!(ticks > 4 * cap, "longer than the trace: {ticks} ticks, {cap} kept");
        assert!(rec.truth.len() <= cap && rec.truth.len() > cap / 2, "{}", rec.truth.len());
        let eval = evaluate(&plan, &rec, "embedded");
        let m = &eval.metrics;
        assert_eq!(m.samples, ticks);
        // Half the ticks 1 mm off: RMS 1 mm / sqrt(2) (to the tick on either side of 100 s).
        let rms = m.object.position_rms_m;
        assert!((rms - 1e-3 / 2f64.sqrt()).abs() < 1e-8, "{rms}");
        assert!((m.object.position_max_m - 1e-3).abs() < 1e-12);
        // The last 30 s at 1 mm against the first 30 at 0, as the batch measure gives it.
        let times: Vec<f64> =
            (1..=ticks as u64).map(|k| k as f64 / plan.scenario.control_hz).collect();
        let errors: Vec<f64> = times.iter().map(|t| if *t >= 100.0 { 1e-3 } else { 0.0 }).collect();
        let batch = metrics::growth(&times, &errors, GROWTH_WINDOW).expect("three windows");
        let growth = m.object_error_growth_m.expect("a long run");
        assert!((growth - batch).abs() < 1e-12 && (growth - 1e-3).abs() < 1e-12, "{growth}");
        assert!(eval.series.len() <= crate::tally::SERIES_ROWS);
        assert!(eval.series.len() > crate::tally::SERIES_ROWS / 4, "{}", eval.series.len());
        assert!(eval.series.time.last().is_some_and(|t| *t > 199.0), "to the end");
    }
}
