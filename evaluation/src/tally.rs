//! A run's measures taken as its messages come, in memory that does not grow with the run:
//! running sums and maxima for the tracking errors, slips, forces and torques, histograms for
//! the percentiles ([`Quantiles`]), the last [`GROWTH_WINDOW`] of the object's error, and
//! time series kept at [`SERIES_HZ`] and halved in rate whenever they reach
//! [`SERIES_ROWS`]. Every measure of `metrics.json` comes from here; a run of an hour is
//! measured as exactly as one of ten seconds.
//!
//! Ground truth is measured [`RELEASE_LAG`] samples after it came, so that a release the
//! coordinator reports a little after its tick halts the walk's references of every sample
//! after it (the references a sample is judged against are those the driver sent).

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use protocol::{DriveCommand, GroundTruth, Pose, TickDiagnostics};

use crate::evaluate::{Recovery, YieldReport, GROWTH_WINDOW, RECOVERY_AFTER, SERIES_HZ};
use crate::loop_timing::LoopTally;
use crate::metrics::{self, DropDetector, Quantiles, RunningRms};
use crate::report::{BoundedSeries, TimeSeries};
use scenario::{Plan, ReferencePlan};

/// Ground truth waits this many samples before it is measured.
pub const RELEASE_LAG: usize = 256;
/// A series holds at most this many rows; past it, every other row goes and the rate halves.
pub const SERIES_ROWS: usize = 1 << 14;
/// Ticks kept in view for the torques' first-per-tick rule and for rows still missing a
/// robot.
pub const RECENT_TICKS: u64 = 4096;

pub(crate) fn iso(p: &Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(Vector3::from(p.position)),
        protocol::conventions::quat_from_wxyz(p.orientation),
    )
}

/// Rotation vector of `q` relative to `q0` in the world frame (`log(q q0^-1)`), for plots.
fn rotvec(q: &UnitQuaternion<f64>, q0: &UnitQuaternion<f64>) -> Vector3<f64> {
    (q * q0.inverse()).scaled_axis()
}

/// What the run measures against: the plan's robots and the references sent.
#[derive(Debug, Clone)]
pub struct RunView {
    pub plan: Plan,
    /// The references the run sent: a walk halts when the team lets go (`launch::driver`).
    pub refs: ReferencePlan,
    pub robots: Vec<String>,
}

impl RunView {
    fn of(plan: &Plan) -> RunView {
        RunView {
            plan: plan.clone(),
            refs: plan.references.clone(),
            robots: plan.robots.iter().map(|r| r.id.clone()).collect(),
        }
    }

    /// Whether a fault stops or stalls robot `r`'s agent: its drives lose their commands (they
    /// fall, or freeze); its torso, palm and hand contact are reported, not judged.
    pub fn faulted(&self, r: &str) -> bool {
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

/// The largest error over one push's recovery window.
#[derive(Debug, Clone)]
struct RecoveryWindow {
    on: String,
    push_end: f64,
    from: f64,
    to: f64,
    /// The pushed robot's index (pushes on a robot).
    robot: Option<usize>,
    object: Option<f64>,
    torso: Option<f64>,
}

/// The object's position error RMS over the run's first [`GROWTH_WINDOW`] and its last.
#[derive(Debug, Clone, Default)]
struct Growth {
    first_t: Option<f64>,
    first: RunningRms,
    last: VecDeque<(f64, f64)>,
}

impl Growth {
    fn add(&mut self, t: f64, e: f64) {
        let t0 = *self.first_t.get_or_insert(t);
        if t < t0 + GROWTH_WINDOW {
            self.first.add(e);
        }
        self.last.push_back((t, e));
        while self.last.front().is_some_and(|(s, _)| *s < t - GROWTH_WINDOW) {
            self.last.pop_front();
        }
    }

    /// As [`metrics::growth`] gives it over the whole series.
    fn value(&self) -> Option<f64> {
        let (first, last) = (self.first_t?, self.last.back()?.0);
        if last - first < 3.0 * GROWTH_WINDOW {
            return None;
        }
        Some(metrics::rms(self.last.iter().map(|(_, e)| *e)) - self.first.rms())
    }
}

/// The measures of the ground truth, sample by sample.
#[derive(Debug, Clone)]
pub struct TruthTally {
    pub series: BoundedSeries,
    pub samples: usize,
    pub last_time: Option<f64>,
    pub object_position: RunningRms,
    pub object_angle: RunningRms,
    pub torso_position: Vec<RunningRms>,
    pub torso_angle: Vec<RunningRms>,
    drop: DropDetector,
    /// Each palm's first position and orientation in the object frame.
    palm0: Vec<Option<(Vector3<f64>, UnitQuaternion<f64>)>>,
    /// Largest displacement of each palm on the object since its first sample, m.
    pub slip: Vec<f64>,
    /// Sum over the samples of each hand's normal force, N.
    pub squeeze_sum: Vec<f64>,
    growth: Growth,
    recoveries: Vec<RecoveryWindow>,
}

impl TruthTally {
    fn new(run: &RunView) -> TruthTally {
        let n = run.robots.len();
        let every = run.refs.clock.ticks_per_sample(SERIES_HZ);
        let hands = run.robots.iter().filter(|r| !run.faulted(r)).count();
        TruthTally {
            series: BoundedSeries::new(&series_columns(&run.robots), every, SERIES_ROWS),
            samples: 0,
            last_time: None,
            object_position: RunningRms::default(),
            object_angle: RunningRms::default(),
            torso_position: vec![RunningRms::default(); n],
            torso_angle: vec![RunningRms::default(); n],
            drop: DropDetector::new(run.refs.object_start.0.z, hands, 0.05, 0.10),
            palm0: vec![None; n],
            slip: vec![0.0; n],
            squeeze_sum: vec![0.0; n],
            growth: Growth::default(),
            recoveries: recovery_windows(run),
        }
    }

    /// Measure one sample (one with the object) against the references at its time.
    fn add(&mut self, run: &RunView, g: &GroundTruth) {
        let Some(object) = &g.object else { return };
        let mut row = Vec::with_capacity(self.series.width());
        let o = iso(&object.pose);
        let (ep, ea) = self.object_columns(run, g.time, &o, &mut row);
        let torso_err = self.torso_columns(run, g, &mut row);
        let flags = self.hand_columns(run, g, &o, &mut row);
        row.push(ep);
        row.push(ea.to_degrees());
        self.drop.add(g.time, o.translation.vector.z, &flags);
        self.growth.add(g.time, ep);
        for w in self.recoveries.iter_mut().filter(|w| g.time >= w.from && g.time <= w.to) {
            w.object = Some(w.object.map_or(ep, |m| m.max(ep)));
            if let Some(e) = w.robot.map(|i| torso_err[i]) {
                w.torso = Some(w.torso.map_or(e, |m| m.max(e)));
            }
        }
        self.series.offer(g.time, &row);
        self.samples += 1;
        self.last_time = Some(g.time);
    }

    /// The object's reference and measured pose (rotations as rotation vectors from the start
    /// orientation); its position and orientation errors.
    fn object_columns(
        &mut self,
        run: &RunView,
        t: f64,
        o: &Isometry3<f64>,
        row: &mut Vec<f64>,
    ) -> (f64, f64) {
        let o_q0 = run.refs.object_start.1;
        let od = iso(&run.refs.object_at(Some(t)).pose);
        let ep = (o.translation.vector - od.translation.vector).norm();
        let ea = metrics::geodesic_angle(&o.rotation, &od.rotation);
        self.object_position.add(ep);
        self.object_angle.add(ea);
        let (rd, rm) = (rotvec(&od.rotation, &o_q0), rotvec(&o.rotation, &o_q0));
        for a in 0..3 {
            row.push(od.translation.vector[a]);
            row.push(o.translation.vector[a]);
        }
        for a in 0..3 {
            row.push(rd[a]);
            row.push(rm[a]);
        }
        (ep, ea)
    }

    /// Each torso's reference and measured position, and its errors; the position errors.
    fn torso_columns(&mut self, run: &RunView, g: &GroundTruth, row: &mut Vec<f64>) -> Vec<f64> {
        let mut errors = Vec::with_capacity(run.robots.len());
        for (i, r) in run.robots.iter().enumerate() {
            let tr = iso(&run.refs.torso_at(i, Some(g.time)).pose);
            let tm = g.torsos.iter().find(|b| &b.name == r).map(|b| iso(&b.pose)).unwrap_or(tr);
            let e = (tm.translation.vector - tr.translation.vector).norm();
            self.torso_position[i].add(e);
            self.torso_angle[i].add(metrics::geodesic_angle(&tm.rotation, &tr.rotation));
            errors.push(e);
            for a in 0..3 {
                row.push(tr.translation.vector[a]);
                row.push(tm.translation.vector[a]);
            }
        }
        errors
    }

    /// Each hand's normal force on the object (`o`), how far its palm slid and turned on the
    /// object since the start, and its contacts; whether each robot not faulted has a hand on
    /// the object.
    fn hand_columns(
        &mut self,
        run: &RunView,
        g: &GroundTruth,
        o: &Isometry3<f64>,
        row: &mut Vec<f64>,
    ) -> Vec<bool> {
        let mut flags = Vec::with_capacity(run.robots.len());
        for (i, r) in run.robots.iter().enumerate() {
            // Normal force: along the palm's outward normal (hand frame z), what the hand
            // applies to the object.
            let palm = g.hands.iter().find(|b| &b.name == r).map(|b| iso(&b.pose));
            let n = palm.map(|p| p.rotation * Vector3::z()).unwrap_or_else(Vector3::zeros);
            let mine = || g.hand_contacts.iter().filter(|c| &c.robot == r);
            let f: f64 =
                mine().map(|c| n.dot(&Vector3::new(c.wrench[0], c.wrench[1], c.wrench[2]))).sum();
            row.push(f);
            self.squeeze_sum[i] += f;
            if !run.faulted(r) {
                flags.push(mine().next().is_some());
            }
            // Where the palm is on the object, and how far it turned on it, since the start.
            let (mut slip_now, mut turn_now) = (0.0, 0.0);
            if let Some(p) = palm {
                let local = o.inverse_transform_point(&p.translation.vector.into()).coords;
                let rel = o.rotation.inverse() * p.rotation;
                let (p0, q0) = *self.palm0[i].get_or_insert((local, rel));
                slip_now = (local - p0).norm();
                turn_now = metrics::geodesic_angle(&q0, &rel).to_degrees();
                self.slip[i] = self.slip[i].max(slip_now);
            }
            row.push(slip_now);
            row.push(turn_now);
            row.push(mine().count() as f64);
        }
        flags
    }

    /// Whether and when the object was dropped.
    pub fn drop_report(&self) -> metrics::DropReport {
        self.drop.report()
    }

    /// The object's error growth, last window against the first (`None` under three windows).
    pub fn growth(&self) -> Option<f64> {
        self.growth.value()
    }

    /// Recovery after each push.
    pub fn recoveries(&self) -> Vec<Recovery> {
        self.recoveries
            .iter()
            .map(|w| Recovery {
                on: w.on.clone(),
                push_end_s: w.push_end,
                object_error_after_m: w.object,
                torso_error_after_m: w.torso,
            })
            .collect()
    }
}

/// Each push's recovery window: from push end + [`RECOVERY_AFTER`] until the next push starts.
fn recovery_windows(run: &RunView) -> Vec<RecoveryWindow> {
    let pushes = &run.plan.scene.perturbations;
    let mut windows = Vec::new();
    for p in pushes {
        let end = p.start + p.duration;
        let next =
            pushes.iter().map(|q| q.start).filter(|s| *s > p.start).fold(f64::INFINITY, f64::min);
        let from = end + RECOVERY_AFTER;
        let to = from + (next - end - RECOVERY_AFTER).max(0.0);
        let (on, robot) = match &p.target {
            protocol::PerturbationTarget::Object => ("object".to_string(), None),
            protocol::PerturbationTarget::RobotBody { robot, body } => {
                (format!("{robot}/{body}"), run.robots.iter().position(|r| r == robot))
            }
        };
        windows.push(RecoveryWindow {
            on,
            push_end: end,
            from,
            to,
            robot,
            object: None,
            torso: None,
        });
    }
    windows
}

/// The torques commanded: one sample per robot and tick (the first heard), each joint's RMS,
/// and rows of every robot's torques at the series' rate.
#[derive(Debug, Clone)]
pub struct TorqueTally {
    robots: Vec<String>,
    /// Per robot, the ticks heard lately (the first command of a tick counts).
    recent: Vec<BTreeSet<u64>>,
    pub rms: Vec<Vec<RunningRms>>,
    /// Rows waiting for a robot's torques, by tick.
    pending: BTreeMap<u64, Vec<Option<Vec<f64>>>>,
    every: u64,
    pub series: BoundedSeries,
}

impl TorqueTally {
    fn new(plan: &Plan) -> TorqueTally {
        let names: Vec<String> = plan
            .robots
            .iter()
            .flat_map(|r| r.joints.iter().map(move |j| format!("{}_{j}", r.id)))
            .collect();
        let n = plan.robots.len();
        TorqueTally {
            robots: plan.robots.iter().map(|r| r.id.clone()).collect(),
            recent: vec![BTreeSet::new(); n],
            rms: vec![Vec::new(); n],
            pending: BTreeMap::new(),
            every: plan.references.clock.ticks_per_sample(SERIES_HZ),
            series: BoundedSeries::new(&names, 1, SERIES_ROWS),
        }
    }

    /// Whether robot `i` was heard for `tick` (among the last [`RECENT_TICKS`] it was heard
    /// for).
    pub fn heard(&self, i: usize, tick: u64) -> bool {
        self.recent.get(i).is_some_and(|s| s.contains(&tick))
    }

    /// The last tick robot `i` was heard for.
    pub fn last_tick(&self, i: usize) -> Option<u64> {
        self.recent.get(i).and_then(|s| s.last().copied())
    }

    fn add(&mut self, cmd: &DriveCommand, time: impl Fn(u64) -> f64) {
        let Some(i) = self.robots.iter().position(|r| r == cmd.header.robot_id()) else { return };
        let tick = cmd.header.tick;
        if !self.recent[i].insert(tick) {
            return;
        }
        while self.recent[i].len() as u64 > RECENT_TICKS {
            self.recent[i].pop_first();
        }
        let rms = &mut self.rms[i];
        if rms.is_empty() {
            rms.resize(cmd.tau_ff.len(), RunningRms::default());
        }
        for (a, x) in rms.iter_mut().zip(&cmd.tau_ff) {
            a.add(*x);
        }
        if tick.is_multiple_of(self.every) {
            self.row(i, tick, cmd.tau_ff.clone(), time);
        }
    }

    /// Robot `i`'s torques of `tick` into its row; a complete row goes to the series.
    fn row(&mut self, i: usize, tick: u64, tau: Vec<f64>, time: impl Fn(u64) -> f64) {
        let n = self.robots.len();
        let slot = self.pending.entry(tick).or_insert_with(|| vec![None; n]);
        slot[i] = Some(tau);
        if slot.iter().all(Option::is_some) {
            let row: Vec<f64> = slot.iter().flatten().flatten().copied().collect();
            self.pending.remove(&tick);
            if row.len() == self.series.width() {
                self.series.offer(time(tick), &row);
            }
        }
        while self.pending.first_key_value().is_some_and(|(k, _)| k + RECENT_TICKS < tick) {
            self.pending.pop_first();
        }
    }
}

/// What the coordinator's tick diagnostics add up to.
#[derive(Debug, Clone, Default)]
pub struct DiagnosticsTally {
    pub qp_status: BTreeMap<String, u64>,
    pub fallback_ticks: BTreeMap<String, u64>,
    pub motion_yield: Option<YieldReport>,
    pub grasp_fit_residual_max: f64,
    pub grasp_refits: u64,
    pub grasp_slip_since_closed_max: f64,
    pub release: Option<String>,
    pub qp_iterations: Quantiles,
    pub qp_solve_us: Quantiles,
    pub controller_tick_us: Quantiles,
}

impl DiagnosticsTally {
    fn add(&mut self, d: &TickDiagnostics) {
        *self.qp_status.entry(format!("{:?}", d.qp_status)).or_insert(0) += 1;
        if let Some(f) = d.fallback.as_deref() {
            *self.fallback_ticks.entry(fallback_kind(f).to_string()).or_insert(0) += 1;
            if self.release.is_none() && f.starts_with("grasp released at tick") {
                self.release = Some(f.to_string());
            }
        }
        if let Some(y) = d.motion_yield {
            YieldReport::add(&mut self.motion_yield, d.header.tick, &y);
        }
        self.grasp_fit_residual_max = self.grasp_fit_residual_max.max(d.grasp_slip);
        self.grasp_refits = self.grasp_refits.max(d.grasp_refits);
        self.grasp_slip_since_closed_max =
            self.grasp_slip_since_closed_max.max(d.grasp_slip_since_closed);
        self.qp_iterations.add(d.qp_iterations as f64);
        self.qp_solve_us.add(d.qp_solve_us);
        self.controller_tick_us.add(d.total_us);
    }
}

/// What a command that did not come from the controller's normal path was, grouped by what
/// was done, not by the numbers in the message.
fn fallback_kind(f: &str) -> &'static str {
    if f.starts_with("controller error") {
        "hold orders after a controller error"
    } else if f.starts_with("controller not ready") {
        "hold orders: controller not ready"
    } else if f.starts_with("grasp released") {
        "grasp released (hands free, feet only)"
    } else {
        "QP fallback"
    }
}

/// Every measure of a run, taken as its messages come.
#[derive(Debug, Clone)]
pub struct Tally {
    pub run: RunView,
    /// Ground truth not yet measured ([`RELEASE_LAG`]).
    lag: VecDeque<GroundTruth>,
    pub truth: TruthTally,
    pub torques: TorqueTally,
    pub diagnostics: DiagnosticsTally,
    pub loop_timing: LoopTally,
}

impl Tally {
    pub fn new(plan: &Plan) -> Tally {
        let run = RunView::of(plan);
        Tally {
            truth: TruthTally::new(&run),
            torques: TorqueTally::new(plan),
            diagnostics: DiagnosticsTally::default(),
            loop_timing: LoopTally::default(),
            lag: VecDeque::with_capacity(RELEASE_LAG + 1),
            run,
        }
    }

    /// A scenario tick's ground truth.
    pub fn add_truth(&mut self, g: GroundTruth) {
        self.loop_timing.add(&g);
        self.lag.push_back(g);
        if self.lag.len() > RELEASE_LAG {
            if let Some(g) = self.lag.pop_front() {
                self.truth.add(&self.run, &g);
            }
        }
    }

    /// A scenario tick's drive command.
    pub fn add_drive(&mut self, cmd: &DriveCommand) {
        let refs = &self.run.refs;
        self.torques.add(cmd, |tick| refs.time_of_tick(tick).unwrap_or(0.0));
    }

    /// A scenario tick's diagnostics.
    pub fn add_diagnostics(&mut self, d: &TickDiagnostics) {
        self.diagnostics.add(d);
    }

    /// The team let go after `tick`: the walk's references halt (`ReferencePlan::halt_walk`).
    pub fn released(&mut self, tick: u64) {
        self.run.refs.halt_walk(tick);
    }

    /// Every sample measured: the tally at the end of the run.
    pub fn finished(&self) -> Tally {
        let mut done = self.clone();
        while let Some(g) = done.lag.pop_front() {
            done.truth.add(&done.run, &g);
        }
        done
    }

    /// The scenario time of the last sample with the object.
    pub fn last_time(&self) -> Option<f64> {
        self.lag.iter().rev().find(|g| g.object.is_some()).map(|g| g.time).or(self.truth.last_time)
    }

    /// The truth series and the torque series as they stand.
    pub fn series(&self) -> (TimeSeries, TimeSeries) {
        (self.truth.series.series().clone(), self.torques.series.series().clone())
    }
}
