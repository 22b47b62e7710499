//! From a run's records to the report: every measure of success (`metrics.json`; see
//! `docs/scenarios.md`), the time series (`timeseries.csv`, `torques.csv`) and the
//! acceptance checks of the team demo. Measured values come from the ground truth only. A run
//! that ended in an error is measured over the ticks it saw, the error named in the report
//! ([`evaluate_failed`]).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use protocol::{GroundTruth, Pose, PoseReference};
use robot_agent::delay::TeamDelay;
use serde::Serialize;

use crate::metrics::{self, DropReport, Percentiles};
use crate::records::Records;
use crate::report::{self, ReportError, TimeSeries};
use scenario::{Plan, ReferencePlan};

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
    fn of(records: &Records) -> Option<YieldReport> {
        let yields: Vec<(u64, protocol::MotionYield)> = records
            .diagnostics
            .iter()
            .filter_map(|d| d.motion_yield.map(|y| (d.header.tick, y)))
            .collect();
        let (first, last) = (yields.first()?.0, yields.last()?.0);
        Some(YieldReport {
            ticks: yields.len() as u64,
            first_tick: first,
            last_tick: last,
            least_object_share: yields.iter().map(|(_, y)| y.object).fold(1.0, f64::min),
            object_still_ticks: yields.iter().filter(|(_, y)| y.object == 0.0).count() as u64,
            torso_ticks: yields.iter().filter(|(_, y)| y.torso < 1.0).count() as u64,
        })
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

fn iso(p: &Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(Vector3::from(p.position)),
        protocol::conventions::quat_from_wxyz(p.orientation),
    )
}

fn ref_iso(r: &PoseReference) -> Isometry3<f64> {
    iso(&r.pose)
}

/// Rotation vector of `q` relative to `q0` in the world frame (`log(q q0^-1)`), for plots.
fn rotvec(q: &UnitQuaternion<f64>, q0: &UnitQuaternion<f64>) -> Vector3<f64> {
    (q * q0.inverse()).scaled_axis()
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
    let refs = references_sent(plan, records);
    let robots = plan.robots.iter().map(|r| r.id.clone()).collect();
    let run = RunView { plan, refs: &refs, robots, mode };
    let truth: Vec<&GroundTruth> = records.truth.iter().filter(|g| g.object.is_some()).collect();
    let every = refs.clock.ticks_per_sample(SERIES_HZ) as usize;
    let pass = TruthPass::over(&run, &truth, every);
    let (torque_rms, torques) = torque_series(plan, records, &refs, every);
    // A failed run is judged up to its last sample (scenario time; 0 without one).
    let until = error.map(|_| records.truth.last().map_or(0.0, |g| g.time));
    let mut metrics = measures(&run, records, &truth, &pass, torque_rms, until);
    metrics.error = error.map(str::to_string);
    metrics.checks = acceptance(&run, &metrics);
    metrics.passed = metrics.checks.iter().all(|c| c.passed);
    Evaluation { metrics, series: pass.series, torques }
}

/// Every measure of the run (no error, no checks yet), from the pass over the ground truth,
/// the torques' RMS and the records; a run judged `until` a scenario time ended there.
fn measures(
    run: &RunView,
    records: &Records,
    truth: &[&GroundTruth],
    pass: &TruthPass,
    torque_rms: BTreeMap<String, Vec<(String, f64)>>,
    until: Option<f64>,
) -> Metrics {
    let (plan, refs) = (run.plan, run.refs);
    let n = truth.len().max(1) as f64;
    let sim = until.unwrap_or_else(|| refs.clock.scenario_duration());
    let walk = refs.walk.as_ref();
    Metrics {
        scenario: plan.scenario.name.clone(),
        mode: run.mode.to_string(),
        error: None,
        duration_s: plan.scenario.duration,
        control_hz: plan.scenario.control_hz,
        physics_hz: plan.scenario.physics_hz,
        team_hz: plan.scenario.control_hz / plan.scenario.team_every().unwrap_or(1) as f64,
        team_delay_ticks: team_delay_ticks(plan, records),
        team_delay_auto: plan.scenario.team_delay_ticks.adapts(),
        drive_gains: plan.scenario.drive_gains.to_string(),
        samples: truth.len(),
        ticks_seen: records.ticks_seen,
        ticks_planned: plan.total_ticks(),
        object: tracking(&pass.obj_pos_err, &pass.obj_ang_err),
        torsos: per_robot(&run.robots, |i| {
            tracking(&pass.torso_pos_err[i], &pass.torso_ang_err[i])
        }),
        drop: pass.drop(refs.object_start.0.z),
        slip_m: per_robot(&run.robots, |i| metrics::slip(&pass.palm_in_object[i])),
        mean_squeeze_n: per_robot(&run.robots, |i| pass.squeeze_sum[i] / n),
        torque_rms,
        qp_status: qp_status_counts(records),
        fallback_ticks: fallback_counts(records),
        motion_yield: YieldReport::of(records),
        grasp_fit_residual_max_m: grasp_fit_residual_max(records),
        grasp_refits: records.diagnostics.iter().map(|d| d.grasp_refits).max().unwrap_or(0),
        grasp_slip_since_closed_max_m: grasp_slip_since_closed_max(records),
        object_error_growth_m: metrics::growth(&pass.times, &pass.obj_pos_err, GROWTH_WINDOW),
        release: release_note(records),
        qp_iterations: diagnostics_percentiles(records, |d| d.qp_iterations as f64),
        qp_solve_us: diagnostics_percentiles(records, |d| d.qp_solve_us),
        controller_tick_us: diagnostics_percentiles(records, |d| d.total_us),
        coordinator_deadline_misses: records.last_status.as_ref().map(|s| s.deadline_misses),
        loop_timing: crate::loop_timing::LoopReport::from_truth(&records.truth),
        coordinator_fallbacks: records.last_status.as_ref().map(|s| s.fallbacks),
        recoveries: recoveries(run, pass),
        walk: walk.map(|w| crate::walking::evaluate(w, truth, refs.walk_halted_at, until)),
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

/// Percentiles of one quantity of the coordinator's tick diagnostics.
fn diagnostics_percentiles(
    records: &Records,
    f: impl Fn(&protocol::TickDiagnostics) -> f64,
) -> Percentiles {
    metrics::percentiles(&records.diagnostics.iter().map(f).collect::<Vec<_>>())
}

/// Largest residual of the controller's object-pose fit over the run, m.
/// The coordinator's note on the tick it let go of the object: its tick and its cause.
fn release_note(records: &Records) -> Option<String> {
    let notes = records.diagnostics.iter().filter_map(|d| d.fallback.as_deref());
    notes.into_iter().find(|f| f.starts_with("grasp released at tick")).map(str::to_string)
}

fn grasp_slip_since_closed_max(records: &Records) -> f64 {
    records.diagnostics.iter().map(|d| d.grasp_slip_since_closed).fold(0.0, f64::max)
}

fn grasp_fit_residual_max(records: &Records) -> f64 {
    records.diagnostics.iter().map(|d| d.grasp_slip).fold(0.0, f64::max)
}

/// Simulated seconds per wall-clock second of the run (0 without a run).
fn real_time_factor(sim: f64, run_wall: std::time::Duration) -> f64 {
    if run_wall.is_zero() {
        0.0
    } else {
        sim / run_wall.as_secs_f64()
    }
}

/// The references the run sent: a walk halts when the team lets go (launch::driver).
fn references_sent(plan: &Plan, records: &Records) -> ReferencePlan {
    let mut halted = plan.references.clone();
    if let Some(tick) = records.released_at {
        halted.halt_walk(tick);
    }
    halted
}

/// The run being evaluated: its plan, the references it sent, its robots' ids and its mode's
/// name.
struct RunView<'a> {
    plan: &'a Plan,
    refs: &'a ReferencePlan,
    robots: Vec<String>,
    mode: &'a str,
}

impl RunView<'_> {
    /// Whether a fault stops or stalls robot `r`'s agent: its drives lose their commands (they
    /// fall, or freeze); its torso, palm and hand contact are reported, not judged.
    fn faulted(&self, r: &str) -> bool {
        self.plan.scenario.faults.iter().any(|f| f.robot() == Some(r))
    }
}

/// The time series' columns: the object's and each torso's reference and measured pose, each
/// hand's contact, and the object's errors.
fn series_columns(robots: &[String]) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for a in ["x", "y", "z", "rx", "ry", "rz"] {
        names.push(format!("object_{a}_des"));
        names.push(format!("object_{a}_mrt"));
    }
    for r in robots {
        for a in ["x", "y", "z"] {
            names.push(format!("{r}_torso_{a}_des"));
            names.push(format!("{r}_torso_{a}_mrt"));
        }
    }
    for r in robots {
        names.push(format!("{r}_hand_normal_force"));
        names.push(format!("{r}_palm_slip"));
        names.push(format!("{r}_palm_turn_deg"));
        names.push(format!("{r}_hand_contacts"));
    }
    names.push("object_position_error".into());
    names.push("object_orientation_error_deg".into());
    names
}

/// What one pass over the ground truth gathers, sample by sample: the time series (every
/// `every`-th sample) and every tick's errors, hand contacts and palms on the object.
struct TruthPass {
    series: TimeSeries,
    times: Vec<f64>,
    object_z: Vec<f64>,
    obj_pos_err: Vec<f64>,
    obj_ang_err: Vec<f64>,
    torso_pos_err: Vec<Vec<f64>>,
    torso_ang_err: Vec<Vec<f64>>,
    /// Per sample, whether each robot not faulted has a hand on the object.
    hand_contact: Vec<Vec<bool>>,
    /// Each palm's position in the object frame, per sample.
    palm_in_object: Vec<Vec<Vector3<f64>>>,
    /// Each palm's first orientation relative to the object.
    palm_rot0: Vec<Option<UnitQuaternion<f64>>>,
    /// Sum over the samples of each hand's normal force, N.
    squeeze_sum: Vec<f64>,
}

impl TruthPass {
    /// Go through `truth` (references at the ground truth's time: the end of the tick's step).
    fn over(run: &RunView, truth: &[&GroundTruth], every: usize) -> TruthPass {
        let n = run.robots.len();
        let names = series_columns(&run.robots);
        let mut pass = TruthPass {
            series: TimeSeries::with_columns(&names),
            times: Vec::new(),
            object_z: Vec::new(),
            obj_pos_err: Vec::new(),
            obj_ang_err: Vec::new(),
            torso_pos_err: vec![Vec::new(); n],
            torso_ang_err: vec![Vec::new(); n],
            hand_contact: Vec::new(),
            palm_in_object: vec![Vec::new(); n],
            palm_rot0: vec![None; n],
            squeeze_sum: vec![0.0; n],
        };
        for (sample, g) in truth.iter().enumerate() {
            let mut row = Vec::with_capacity(names.len());
            let (o, ep, ea) = pass.object_columns(run, g, &mut row);
            pass.torso_columns(run, g, &mut row);
            pass.hand_columns(run, g, &o, &mut row);
            row.push(ep);
            row.push(ea.to_degrees());
            if sample % every == 0 {
                pass.series.push(g.time, &row);
            }
        }
        pass
    }

    /// Whether and when the object was dropped ([`metrics::detect_drop`]: a hand without
    /// contact for 50 ms, or the object 10 cm below `z0`, its start height).
    fn drop(&self, z0: f64) -> DropReport {
        metrics::detect_drop(&self.times, &self.object_z, z0, &self.hand_contact, 0.05, 0.10)
    }

    /// The object's reference and measured pose (rotations as rotation vectors from the start
    /// orientation); its measured pose and position and orientation errors.
    fn object_columns(
        &mut self,
        run: &RunView,
        g: &GroundTruth,
        row: &mut Vec<f64>,
    ) -> (Isometry3<f64>, f64, f64) {
        let t = g.time;
        let o_q0 = run.refs.object_start.1;
        let o = iso(&g.object.as_ref().expect("filtered").pose);
        let od = ref_iso(&run.refs.object_at(Some(t)));
        let ep = (o.translation.vector - od.translation.vector).norm();
        let ea = metrics::geodesic_angle(&o.rotation, &od.rotation);
        self.obj_pos_err.push(ep);
        self.obj_ang_err.push(ea);
        self.times.push(t);
        self.object_z.push(o.translation.vector.z);
        let (rd, rm) = (rotvec(&od.rotation, &o_q0), rotvec(&o.rotation, &o_q0));
        for a in 0..3 {
            row.push(od.translation.vector[a]);
            row.push(o.translation.vector[a]);
        }
        for a in 0..3 {
            row.push(rd[a]);
            row.push(rm[a]);
        }
        (o, ep, ea)
    }

    /// Each torso's reference and measured position, and its errors.
    fn torso_columns(&mut self, run: &RunView, g: &GroundTruth, row: &mut Vec<f64>) {
        for (i, r) in run.robots.iter().enumerate() {
            let tr = ref_iso(&run.refs.torso_at(i, Some(g.time)));
            let tm = g.torsos.iter().find(|b| &b.name == r).map(|b| iso(&b.pose)).unwrap_or(tr);
            self.torso_pos_err[i].push((tm.translation.vector - tr.translation.vector).norm());
            self.torso_ang_err[i].push(metrics::geodesic_angle(&tm.rotation, &tr.rotation));
            for a in 0..3 {
                row.push(tr.translation.vector[a]);
                row.push(tm.translation.vector[a]);
            }
        }
    }

    /// Each hand's normal force on the object (`o`), how far its palm slid and turned on the
    /// object since the start, and its contacts.
    fn hand_columns(
        &mut self,
        run: &RunView,
        g: &GroundTruth,
        o: &Isometry3<f64>,
        row: &mut Vec<f64>,
    ) {
        let mut flags = Vec::with_capacity(run.robots.len());
        for (i, r) in run.robots.iter().enumerate() {
            // Normal force: along the palm's outward normal (hand frame z), what the hand
            // applies to the object.
            let palm = g.hands.iter().find(|b| &b.name == r).map(|b| iso(&b.pose));
            let n = palm.map(|p| p.rotation * Vector3::z()).unwrap_or_else(Vector3::zeros);
            let f: f64 = g
                .hand_contacts
                .iter()
                .filter(|c| &c.robot == r)
                .map(|c| n.dot(&Vector3::new(c.wrench[0], c.wrench[1], c.wrench[2])))
                .sum();
            row.push(f);
            self.squeeze_sum[i] += f;
            if !run.faulted(r) {
                flags.push(g.hand_contacts.iter().any(|c| &c.robot == r));
            }
            // Where the palm is on the object, and how far it turned on it, since the start.
            let (mut slip_now, mut turn_now) = (0.0, 0.0);
            if let Some(p) = palm {
                let local = o.inverse_transform_point(&p.translation.vector.into()).coords;
                slip_now = self.palm_in_object[i].first().map_or(0.0, |p0| (local - p0).norm());
                self.palm_in_object[i].push(local);
                let rel = o.rotation.inverse() * p.rotation;
                turn_now = metrics::geodesic_angle(self.palm_rot0[i].get_or_insert(rel), &rel)
                    .to_degrees();
            }
            row.push(slip_now);
            row.push(turn_now);
            row.push(g.hand_contacts.iter().filter(|c| &c.robot == r).count() as f64);
        }
        self.hand_contact.push(flags);
    }
}

/// Tracking of a pose task from its position and orientation errors.
fn tracking(pe: &[f64], ae: &[f64]) -> Tracking {
    Tracking {
        position_rms_m: metrics::rms(pe.iter().copied()),
        position_max_m: pe.iter().copied().fold(0.0, f64::max),
        orientation_rms_deg: metrics::rms(ae.iter().copied()).to_degrees(),
        orientation_max_deg: ae.iter().copied().fold(0.0, f64::max).to_degrees(),
    }
}

/// Torques: one sample per tick (the first applied for it), in joint order; each joint's RMS
/// by robot, and the time series of every `every`-th tick all robots have.
fn torque_series(
    plan: &Plan,
    records: &Records,
    refs: &ReferencePlan,
    every: usize,
) -> (BTreeMap<String, Vec<(String, f64)>>, TimeSeries) {
    let mut torque_rms = BTreeMap::new();
    let mut torque_names = Vec::new();
    let mut per_robot: Vec<BTreeMap<u64, &Vec<f64>>> = Vec::new();
    for r in &plan.robots {
        let (id, joints) = (&r.id, &r.joints);
        let by_tick: BTreeMap<u64, &Vec<f64>> = records
            .torques
            .get(id)
            .map(|v| v.iter().rev().map(|(t, tau)| (*t, tau)).collect())
            .unwrap_or_default();
        let samples: Vec<Vec<f64>> = by_tick.values().map(|v| (*v).clone()).collect();
        let rms = metrics::torque_rms(&samples);
        torque_rms.insert(id.clone(), joints.iter().cloned().zip(rms).collect::<Vec<_>>());
        torque_names.extend(joints.iter().map(|j| format!("{id}_{j}")));
        per_robot.push(by_tick);
    }
    let mut torques = TimeSeries::with_columns(&torque_names);
    if let Some(first) = per_robot.first() {
        for (&tick, _) in first.iter().step_by(every) {
            let mut row = Vec::with_capacity(torque_names.len());
            let complete = per_robot.iter().all(|m| m.contains_key(&tick));
            if !complete {
                continue;
            }
            for m in &per_robot {
                row.extend(m[&tick].iter().copied());
            }
            if row.len() == torque_names.len() {
                torques.push(refs.time_of_tick(tick).unwrap_or(0.0), &row);
            }
        }
    }
    (torque_rms, torques)
}

/// Ticks by the QP's status.
fn qp_status_counts(records: &Records) -> BTreeMap<String, u64> {
    let mut qp_status = BTreeMap::new();
    for d in &records.diagnostics {
        *qp_status.entry(format!("{:?}", d.qp_status)).or_insert(0u64) += 1;
    }
    qp_status
}

/// Ticks whose command did not come from the controller's normal path, grouped by what was
/// done, not by the numbers in the message.
fn fallback_counts(records: &Records) -> BTreeMap<String, u64> {
    let mut fallback_ticks = BTreeMap::new();
    for f in records.diagnostics.iter().filter_map(|d| d.fallback.as_deref()) {
        let kind = if f.starts_with("controller error") {
            "hold orders after a controller error"
        } else if f.starts_with("controller not ready") {
            "hold orders: controller not ready"
        } else if f.starts_with("grasp released") {
            "grasp released (hands free, feet only)"
        } else {
            "QP fallback"
        };
        *fallback_ticks.entry(kind.to_string()).or_insert(0u64) += 1;
    }
    fallback_ticks
}

/// Recovery after each push: from push end + [`RECOVERY_AFTER`] until the next push starts.
fn recoveries(run: &RunView, pass: &TruthPass) -> Vec<Recovery> {
    let pushes = &run.plan.scene.perturbations;
    let mut recoveries = Vec::new();
    for p in pushes {
        let end = p.start + p.duration;
        let next =
            pushes.iter().map(|q| q.start).filter(|s| *s > p.start).fold(f64::INFINITY, f64::min);
        let window = (next - end - RECOVERY_AFTER).max(0.0);
        let (on, torso_err) = match &p.target {
            protocol::PerturbationTarget::Object => ("object".to_string(), None),
            protocol::PerturbationTarget::RobotBody { robot, body } => {
                let i = run.robots.iter().position(|r| r == robot);
                (
                    format!("{robot}/{body}"),
                    i.and_then(|i| {
                        metrics::recovery_error(
                            &pass.times,
                            &pass.torso_pos_err[i],
                            end,
                            RECOVERY_AFTER,
                            window,
                        )
                    }),
                )
            }
        };
        recoveries.push(Recovery {
            on,
            push_end_s: end,
            object_error_after_m: metrics::recovery_error(
                &pass.times,
                &pass.obj_pos_err,
                end,
                RECOVERY_AFTER,
                window,
            ),
            torso_error_after_m: torso_err,
        });
    }
    recoveries
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
    use protocol::{BodyTruth, ContactTruth, Header};
    use scenario::file::Scenario;
    use scenario::plan;

    fn s4_plan() -> Plan {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf();
        let s = Scenario::load(
            root.join("scenarios/s4_object_circle.toml"),
            &["duration=1.0".into(), "settle=0.0".into()],
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
        let mut rec = Records::default();
        let refs = &plan.references;
        for k in 0..plan.scene.ticks {
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
            rec.truth.push(g);
        }
        rec.ticks_seen = plan.scene.ticks;
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
        let mut rec = records(&plan, |_| 0.0, |_| true);
        let seen = plan.total_ticks() * 2 / 5;
        rec.truth.truncate(seen as usize);
        rec.ticks_seen = seen;
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

        let nothing = Records { ticks_seen: 3, ..Default::default() };
        let empty = evaluate_failed(&plan, &nothing, "embedded", error);
        let m = &empty.metrics;
        assert!(!m.passed && m.samples == 0 && m.real_time_factor == 0.0, "{m:?}");
        assert!(m.object.position_rms_m == 0.0 && !m.drop.dropped);
        write_report(&plan, &empty, &dir).unwrap();
        crate::plots::write_all(&plan, &empty, &nothing, &dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
