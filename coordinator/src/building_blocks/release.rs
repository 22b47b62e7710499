//! Letting go of the object: the last step of "degrade, never collapse".
//!
//! The contact-force QP keeps the stance feet's rows and the torque limits before the hands'
//! (its least-violation fallback weights them so): when the object cannot be held, the hands'
//! rows give first and the object slips. What the fallback cannot fix is the model: the
//! controller keeps treating the hands as rigidly joined through the object (the rows of
//! `J_c,ee` in `P`, the object's load `J_x^T F_x`), so once the object has gone the robots
//! push against a constraint that no longer exists and fall (seen in MuJoCo with two robots and
//! 1.5 times the payload capacity: the object slid out within 0.2 s, the torsos tipped over
//! from 0.3 s).
//!
//! [`GraspWatch`] decides when the team lets go. It watches, after each tick, whether the QP
//! was solved and how far the hands are from where the fitted object puts them (the fit's
//! residual, the controller's own slip signal), and latches a [`Release`] when either
//! [`ReleasePolicy`] limit is passed. While released, the controller treats every hand as free
//! ([`crate::team::Team::hands_released`]): no grasp rows, no object task or load, each hand
//! backs away from the object by [`ReleasePolicy::retreat`] and holds that pose (a free-hand
//! task), and the QP is the stance feet's alone. The latch clears when no robot's contact set
//! has its hand in grasp any more (the grasp was opened), so a later grasp closes as usual.
//! Both PIDC and MQP call [`GraspWatch::after_tick`] as their tick's last step.

use serde::{Deserialize, Serialize};

use crate::building_blocks::grasp::{GraspTerms, GraspTracker, RefitRule};
use crate::building_blocks::targets::Targets;
use crate::team::Team;

/// When the team lets go of the object. Either limit at 0 is never reached.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReleasePolicy {
    /// How long (s, in the robots' time from the first failed tick of a run with no tick solved
    /// between) the contact-force QP may fail (a fallback sent) before the hands let go. A push
    /// makes a few failed ticks; an object the team cannot hold makes them all. A time, not a
    /// count of ticks: what the robots can stand is a time, whatever the loop's rate.
    pub after_failed: f64,
    /// Largest grasp-fit residual (m): a hand this far from where the fitted object pose puts it
    /// means the grasp is no longer rigid (the object slipped out or the palms came apart).
    pub max_fit_residual: f64,
    /// How far each hand backs away from the object when the team lets go (m, horizontally
    /// from the object's centre): holding the palms where they were would keep the object
    /// pinched, its weight on arms that cannot carry it.
    pub retreat: f64,
    /// A hand this far (m) from where the measured object puts its contact has slid on the
    /// object: the grasp model is re-fitted to the measured object, and the slip alone never
    /// lets go (`building_blocks::grasp::GraspTracker::update_refitting`; 0: never re-fitted).
    pub refit_at: f64,
    /// Time at least from one re-fit to the next, s ([`RefitRule::min_ticks`]): slip that comes
    /// faster is left to the fit's residual and [`ReleasePolicy::max_fit_residual`].
    pub refit_min_interval: f64,
    /// How far (m) a hand's contact may move on the object since the grasp closed, re-fits
    /// included, before the team lets go: past it the palm is sliding off the object.
    pub max_slip: f64,
}

impl Default for ReleasePolicy {
    fn default() -> Self {
        // 50 ms of failed ticks (two robots with 1.5 times their payload: releasing within
        // 0.1 s kept both standing, from 0.15 s on they fell); 2 cm, four times the acceptance
        // bound on palm slip; 5 cm clears the palms off the object. A re-fit at 0.5 mm keeps the
        // object's estimate within half a millimetre of the measured object; 0.25 s apart
        // follows creep (0.5 mm takes seconds) and not a hand being dragged off the object
        // (0.3-0.6 mm per millisecond).
        ReleasePolicy {
            after_failed: 0.05,
            max_fit_residual: 0.02,
            retreat: 0.05,
            refit_at: 0.0005,
            refit_min_interval: 0.25,
            max_slip: 0.05,
        }
    }
}

impl ReleasePolicy {
    /// When the grasp model follows the measured object, for robots ticking every `period` s.
    pub fn refit(&self, period: f64) -> RefitRule {
        RefitRule { at: self.refit_at, min_ticks: ticks_in(self.refit_min_interval, period) }
    }

    /// Finite, non-negative lengths and times.
    pub fn check(&self) -> Result<(), String> {
        for (what, x) in [
            ("after_failed", self.after_failed),
            ("refit_min_interval", self.refit_min_interval),
            ("max_fit_residual", self.max_fit_residual),
            ("retreat", self.retreat),
            ("refit_at", self.refit_at),
            ("max_slip", self.max_slip),
        ] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(format!("{what} {x} must be finite and non-negative"));
            }
        }
        Ok(())
    }
}

/// The robot ticks of `period` s that `time` s spans, at least one (rounded to the nearest:
/// 0.05 s at 1 kHz is 50 ticks).
fn ticks_in(time: f64, period: f64) -> u32 {
    if !(period > 0.0 && time > 0.0) {
        return 0;
    }
    ((time / period).round().max(1.0)).min(f64::from(u32::MAX)) as u32
}

/// Why and when the team let go.
#[derive(Debug, Clone, PartialEq)]
pub struct Release {
    /// The tick after which the hands were released.
    pub tick: u64,
    /// One line for logs and the diagnostics' `fallback` field.
    pub note: String,
}

/// Share of [`ReleasePolicy::max_fit_residual`] at which a tick whose QP failed lets go. A
/// grasp that slips while the contact forces cannot be kept is being lost, and every tick
/// waited drags the hands further: two robots on S4 with a 300 N push on the object (the
/// QP failed on every tick from 27 ms into the push, the slip grew 0.3-0.6 mm per tick)
/// released at 20 mm 53 ticks into the push and one torso fell (0.67 m, with the exact QP
/// optimum); at 10 mm from the first failed tick on, 43 ticks in, both stood within 5 mm, and
/// likewise for 200 N, 450 N and a 2.5 kg object; with the run of
/// [`SLIP_WHILE_FAILING_AFTER`] (10 ms), after 63 failed ticks, both stood within 5.0 mm
/// (`tests/tests/degrade.rs`, README "Degrade, never collapse").
pub const SLIP_WHILE_FAILING: f64 = 0.5;

/// How long the QP has failed before [`SLIP_WHILE_FAILING`] applies, s of the robots' time: a
/// push that the contact forces cannot meet fails tick after tick (the 300 N push above from
/// 27 ms into it on), a robot whose terms came late fails one or two (a three-robot team at
/// 125 Hz with one agent stalled 0.12 s: two infeasible ticks at 10-20 mm of residual, and
/// letting go there dropped an object the team then held through the stall at the full limit).
/// And at least [`SLIP_WHILE_FAILING_MIN_TICKS`], more than a late robot's one or two, at any
/// rate.
pub const SLIP_WHILE_FAILING_AFTER: f64 = 0.010;
/// The fewest failed ticks in a row before [`SLIP_WHILE_FAILING`] applies.
pub const SLIP_WHILE_FAILING_MIN_TICKS: u32 = 3;

/// What one tick showed (see [`GraspWatch::observe`]).
#[derive(Debug, Clone, Copy)]
pub struct GraspObservation {
    pub tick: u64,
    /// The robots' tick period, s.
    pub period: f64,
    /// Hands in grasp as modelled this tick (0 once released).
    pub hands: usize,
    /// The contact-force QP was not solved and a fallback was sent.
    pub qp_failed: bool,
    /// The grasp fit's residual this tick (m), when a grasp was modelled.
    pub fit_residual: Option<f64>,
    /// How far a hand's contact has moved on the object since the grasp closed (m), when a
    /// grasp was modelled (what the re-fits to the measured object followed).
    pub slip_since_closed: Option<f64>,
}

impl GraspObservation {
    /// The outcome of a tick of `team` (its hands in grasp as modelled, robots ticking every
    /// `period` s) with `grasp`'s fit.
    pub fn of(
        (tick, period): (u64, f64),
        team: &Team,
        grasp: Option<&GraspTerms>,
        qp_failed: bool,
    ) -> Self {
        GraspObservation {
            tick,
            period,
            hands: team.hands.len(),
            qp_failed,
            fit_residual: grasp.map(|g| g.fit_residual),
            slip_since_closed: grasp.map(|g| g.slip_since_closed),
        }
    }
}

/// The latch of [`ReleasePolicy`] (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct GraspWatch {
    /// The tick whose QP failed first in the current run of failed ticks.
    failing_since: Option<u64>,
    /// The run's length in the robots' ticks (its last tick - its first + 1): the time the QP
    /// has been failing, not the count of ticks solved. In real time a failing tick takes
    /// longer, the coordinator skips the ticks overtaken meanwhile (S4 at 1 kHz, a 300 N push:
    /// it solved one tick in 4-12) and a count of solved ticks let the slip run on to 31 mm.
    failed_run: u32,
    /// The robots' tick period of the last tick observed, s.
    period: f64,
    /// Hands in grasp on the last tick observed.
    last_hands: usize,
    released: Option<Release>,
}

impl GraspWatch {
    /// The release in force, if the team has let go.
    pub fn released(&self) -> Option<&Release> {
        self.released.as_ref()
    }

    /// Whether slip is followed by re-fitting the grasp model to the measured object: not once
    /// the QP has failed for [`SLIP_WHILE_FAILING_AFTER`] in a row
    /// ([`SLIP_WHILE_FAILING_MIN_TICKS`] at least). Slip while the contact forces
    /// cannot be kept is the grasp being lost (a robot pushed away with its hand on the
    /// object): re-fitted, the fit would never show it, and the team would follow the hand
    /// until the palm slid off, dragging the others after it.
    pub fn follows_slip(&self) -> bool {
        !self.failing_long()
    }

    /// Whether the run of failed ticks has lasted [`SLIP_WHILE_FAILING_AFTER`] and
    /// [`SLIP_WHILE_FAILING_MIN_TICKS`].
    fn failing_long(&self) -> bool {
        self.failed_run >= SLIP_WHILE_FAILING_MIN_TICKS
            && reached(self.failed_for(), SLIP_WHILE_FAILING_AFTER)
    }

    /// The run of failed ticks in time, s (`failed_run` robot periods).
    fn failed_for(&self) -> f64 {
        f64::from(self.failed_run) * self.period
    }

    /// Before a tick: clear the latch when no hand is in grasp any more (the grasp was opened).
    pub fn rearm(&mut self, hands_in_grasp: bool) {
        if !hands_in_grasp {
            self.failing_since = None;
            self.failed_run = 0;
            self.released = None;
        }
    }

    /// After a tick of `team` with `grasp` (the controllers' last step): [`GraspWatch::observe`];
    /// on the tick the team lets go, the hands' targets back away from the object
    /// ([`Targets::let_go`]) and the grasp is forgotten. The release in force, as its note.
    pub fn after_tick(
        &mut self,
        policy: &ReleasePolicy,
        t: GraspObservation,
        team: &Team,
        grasp: Option<&GraspTerms>,
        targets: &mut Targets,
        tracker: &mut GraspTracker,
    ) -> Option<&str> {
        if let Some(release) = self.observe(policy, t) {
            tracing::warn!(tick = release.tick, "{}", release.note);
            if let Some(g) = grasp {
                targets.let_go(team, &g.object.translation.vector, policy.retreat);
            }
            tracker.release();
            targets.release_object();
        }
        self.released.as_ref().map(|r| r.note.as_str())
    }

    /// After a tick: count failed ticks and check the fit; `Some` on the tick the team lets go.
    pub fn observe(&mut self, policy: &ReleasePolicy, t: GraspObservation) -> Option<&Release> {
        let last_hands = std::mem::replace(&mut self.last_hands, t.hands);
        if self.released.is_some() || t.hands == 0 {
            self.failing_since = None;
            self.failed_run = 0;
            return None;
        }
        self.count_failed(t);
        let failed = policy.after_failed > 0.0 && reached(self.failed_for(), policy.after_failed);
        // Slip while the contact forces cannot be kept (the QP failing tick after tick) is a grasp
        // being lost, not a palm rocking: let go at a share of the limit (SLIP_WHILE_FAILING).
        let failing = t.qp_failed && self.failing_long();
        let limit = policy.max_fit_residual * if failing { SLIP_WHILE_FAILING } else { 1.0 };
        let slipped = t.fit_residual.filter(|&r| policy.max_fit_residual > 0.0 && r > limit);
        let slid_off =
            t.slip_since_closed.filter(|&d| policy.max_slip > 0.0 && d > policy.max_slip);
        // A flat palm pushes, it cannot pinch: one hand left of a grasp (a member left the
        // team, its hand went) cannot hold the object. Let go at once.
        let alone = t.hands == 1 && last_hands >= 2;
        if let Some(d) = slid_off {
            let why = format!(
                "a hand has slid {:.1} mm on the object since the grasp closed (limit {:.1} mm)",
                d * 1e3,
                policy.max_slip * 1e3
            );
            return Some(self.latch(t.tick, &why));
        }
        let why = match (failed, slipped, alone) {
            (_, _, true) => format!(
                "one hand is left of the {last_hands} in grasp (a robot left the team), and one \
                 palm cannot hold the object"
            ),
            (_, Some(r), _) => format!(
                "a hand is {:.1} mm from the fitted object (limit {:.1} mm{})",
                r * 1e3,
                limit * 1e3,
                if failing { " while the QP fails" } else { "" }
            ),
            (true, None, _) => format!(
                "the contact-force QP has failed for {:.0} ms ({} ticks)",
                self.failed_for() * 1e3,
                self.failed_run
            ),
            (false, None, false) => return None,
        };
        Some(self.latch(t.tick, &why))
    }

    /// The run of failed ticks with `t`'s outcome, in the robots' ticks from its first.
    fn count_failed(&mut self, t: GraspObservation) {
        if !t.qp_failed {
            self.failing_since = None;
            self.failed_run = 0;
            return;
        }
        let since = *self.failing_since.get_or_insert(t.tick);
        self.failed_run = u32::try_from(t.tick.saturating_sub(since) + 1).unwrap_or(u32::MAX);
        self.period = t.period;
    }

    /// The release of `tick` for the reason `why`, latched.
    fn latch(&mut self, tick: u64, why: &str) -> &Release {
        let note = format!(
            "grasp released at tick {tick}: {why}; the hands back away and hold, the feet carry \
             the robots"
        );
        self.released.insert(Release { tick, note })
    }
}

/// Whether `time` has reached `limit` (a sum of periods, within rounding).
fn reached(time: f64, limit: f64) -> bool {
    time >= limit * (1.0 - 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`SLIP_WHILE_FAILING_AFTER`] in the ticks of [`tick`]'s 1 kHz.
    const SLIP_WHILE_FAILING_TICKS: u32 = 10;

    /// A tick of robots at 1 kHz.
    fn tick(tick: u64, qp_failed: bool, fit_residual: Option<f64>) -> GraspObservation {
        GraspObservation {
            tick,
            period: 0.001,
            hands: 2,
            qp_failed,
            fit_residual,
            slip_since_closed: None,
        }
    }

    #[test]
    fn the_release_waits_the_same_time_at_any_rate() {
        let p = ReleasePolicy { max_fit_residual: 0.0, ..ReleasePolicy::default() };
        // 50 ms of failed ticks: 50 at 1 kHz, 13 at 250 Hz (12.5 rounded up by the run's
        // whole ticks), 7 at 125 Hz.
        for (period, ticks) in [(0.001, 50), (0.004, 13), (0.008, 7)] {
            let mut w = GraspWatch::default();
            for k in 0..ticks - 1 {
                let t = GraspObservation { period, ..tick(k, true, Some(0.0)) };
                assert!(w.observe(&p, t).is_none(), "{period} s: tick {k}");
            }
            let t = GraspObservation { period, ..tick(ticks - 1, true, Some(0.0)) };
            assert!(w.observe(&p, t).is_some(), "{period} s: let go after {ticks} ticks");
        }
        // Slip stops being followed after 10 ms: 10 ticks at 1 kHz, 3 at 250 Hz; never after
        // fewer than three, however slow (a late robot's terms make one or two).
        let never = ReleasePolicy { after_failed: 0.0, ..p };
        for (period, ticks) in [(0.001, 10), (0.004, 3), (0.008, 3), (0.1, 3)] {
            let mut w = GraspWatch::default();
            for k in 0..ticks {
                assert!(w.follows_slip(), "{period} s: tick {k}");
                w.observe(&never, GraspObservation { period, ..tick(k, true, Some(0.0)) });
            }
            assert!(!w.follows_slip(), "{period} s: after {ticks} ticks");
        }
        assert_eq!(p.refit(0.001).min_ticks, 250);
        assert_eq!(p.refit(0.004).min_ticks, 63);
    }

    #[test]
    fn slip_is_not_followed_while_the_qp_keeps_failing() {
        let p = ReleasePolicy::default();
        let mut w = GraspWatch::default();
        for t in 0..SLIP_WHILE_FAILING_TICKS {
            assert!(w.follows_slip(), "tick {t}");
            w.observe(&p, tick(u64::from(t), true, Some(0.0)));
        }
        assert!(!w.follows_slip());
        w.observe(&p, tick(99, false, Some(0.0)));
        assert!(w.follows_slip(), "a solved tick ends the run of failures");
    }

    #[test]
    fn a_run_of_failures_is_counted_in_the_robots_ticks_not_in_ticks_solved() {
        let p = ReleasePolicy::default();
        let half = SLIP_WHILE_FAILING * p.max_fit_residual;
        let n = u64::from(SLIP_WHILE_FAILING_TICKS);
        let mut w = GraspWatch::default();
        // Three failed ticks solved, the ticks between them overtaken: the QP has been failing
        // for n ticks at the third.
        assert!(w.observe(&p, tick(100, true, Some(1.5 * half))).is_none());
        assert!(w.observe(&p, tick(100 + n / 2, true, Some(1.5 * half))).is_none());
        assert!(w.follows_slip());
        let r = w.observe(&p, tick(100 + n - 1, true, Some(1.5 * half))).expect("failing").clone();
        assert!(r.note.contains("while the QP fails"), "{}", r.note);
        // The longer limit likewise.
        let p = ReleasePolicy { after_failed: 0.05, max_fit_residual: 0.0, ..p };
        let mut w = GraspWatch::default();
        assert!(w.observe(&p, tick(0, true, Some(0.0))).is_none());
        assert!(w.observe(&p, tick(48, true, Some(0.0))).is_none());
        let r = w.observe(&p, tick(49, true, Some(0.0))).expect("failed for 50 ticks").clone();
        assert!(r.note.contains("failed for 50 ms (50 ticks)"), "{}", r.note);
    }

    #[test]
    fn a_grasp_left_with_one_hand_releases_at_once_and_a_single_hand_closing_does_not() {
        let p = ReleasePolicy::default();
        let mut w = GraspWatch::default();
        // One hand closing before the other (a contact set a tick ahead) is not a loss.
        assert!(w
            .observe(&p, GraspObservation { hands: 1, ..tick(1, false, Some(0.0)) })
            .is_none());
        for t in 2..5 {
            assert!(w
                .observe(&p, GraspObservation { hands: 3, ..tick(t, false, Some(0.0)) })
                .is_none());
        }
        // Three to two: the rest still hold.
        assert!(w.observe(&p, tick(5, false, Some(0.0))).is_none());
        let r = w
            .observe(&p, GraspObservation { hands: 1, ..tick(6, false, Some(0.0)) })
            .expect("one hand left")
            .clone();
        assert_eq!(r.tick, 6);
        assert!(r.note.contains("one hand is left of the 2"), "{}", r.note);
    }

    #[test]
    fn a_run_of_failed_ticks_releases_and_a_solved_tick_restarts_the_count() {
        let p = ReleasePolicy { after_failed: 0.003, ..ReleasePolicy::default() };
        let mut w = GraspWatch::default();
        assert!(w.observe(&p, tick(1, true, Some(0.0))).is_none());
        assert!(w.observe(&p, tick(2, true, Some(0.0))).is_none());
        assert!(
            w.observe(&p, tick(3, false, Some(0.0))).is_none(),
            "a solved tick restarts the count"
        );
        assert!(w.observe(&p, tick(4, true, Some(0.0))).is_none());
        assert!(w.observe(&p, tick(5, true, Some(0.0))).is_none());
        let r =
            w.observe(&p, tick(6, true, Some(0.0))).expect("three failed ticks in a row").clone();
        assert_eq!(r.tick, 6);
        assert!(r.note.contains("failed for 3 ms (3 ticks)"), "{}", r.note);
        assert!(w.observe(&p, tick(7, true, Some(0.0))).is_none(), "released once");
        assert_eq!(w.released(), Some(&r));
    }

    #[test]
    fn a_slipped_hand_releases_at_once_and_opening_the_grasp_rearms() {
        let p = ReleasePolicy::default();
        let mut w = GraspWatch::default();
        assert!(w.observe(&p, tick(1, false, Some(0.019))).is_none());
        assert!(w
            .observe(&p, tick(2, false, Some(0.021)))
            .expect("past 2 cm")
            .note
            .contains("21.0 mm"));
        w.rearm(true);
        assert!(w.released().is_some(), "still in grasp: still released");
        w.rearm(false);
        assert!(w.released().is_none(), "the grasp was opened");
        assert!(w.observe(&p, tick(3, true, None)).is_none(), "no grasp modelled, one failed tick");
    }

    #[test]
    fn slip_while_the_qp_fails_releases_at_half_the_limit() {
        let p = ReleasePolicy::default();
        let half = SLIP_WHILE_FAILING * p.max_fit_residual;
        let n = u64::from(SLIP_WHILE_FAILING_TICKS);
        // Ticks 1..n-1 fail (runs 1..n-1) past the share: the full limit still holds; tick n
        // (a run of exactly SLIP_WHILE_FAILING_TICKS) lets go.
        let mut w = GraspWatch::default();
        assert!(
            w.observe(&p, tick(0, false, Some(1.5 * half))).is_none(),
            "a solved tick keeps the full limit"
        );
        for k in 1..n {
            assert!(
                w.observe(&p, tick(k, true, Some(1.5 * half))).is_none(),
                "a short run of failed ticks keeps the full limit (tick {k})"
            );
        }
        let r = w
            .observe(&p, tick(n, true, Some(1.1 * half)))
            .expect("slip past the share once the QP has failed the run")
            .clone();
        assert_eq!(r.tick, n);
        assert!(r.note.contains("while the QP fails"), "{}", r.note);
        // The same run below the share does not let go, and a solved tick restarts the run.
        let mut w = GraspWatch::default();
        for k in 1..=n {
            assert!(
                w.observe(&p, tick(k, true, Some(0.9 * half))).is_none(),
                "below the share (tick {k})"
            );
        }
        assert!(
            w.observe(&p, tick(n + 1, false, Some(1.5 * half))).is_none(),
            "a solved tick keeps the full limit"
        );
        assert!(
            w.observe(&p, tick(n + 2, true, Some(1.5 * half))).is_none(),
            "the run starts again"
        );
    }

    #[test]
    fn slip_followed_on_the_object_lets_go_only_past_the_palm() {
        let p = ReleasePolicy::default();
        let slid = |t: u64, d: f64| GraspObservation {
            slip_since_closed: Some(d),
            ..tick(t, false, Some(0.0002))
        };
        let mut w = GraspWatch::default();
        // Minutes of creep, re-fitted to the measured object: held.
        for (t, d) in [(0, 0.0), (1, 0.002), (2, 0.02), (3, 0.9 * p.max_slip)] {
            assert!(w.observe(&p, slid(t, d)).is_none(), "slip {d} m is within the palm");
        }
        let r = w.observe(&p, slid(4, 1.1 * p.max_slip)).expect("slid off the palm").clone();
        assert_eq!(r.tick, 4);
        assert!(r.note.contains("has slid 55.0 mm on the object"), "{}", r.note);
        let off = ReleasePolicy { max_slip: 0.0, ..p };
        assert!(GraspWatch::default().observe(&off, slid(0, 1.0)).is_none(), "0: no limit");
    }

    #[test]
    fn zero_limits_never_release() {
        let p = ReleasePolicy { after_failed: 0.0, max_fit_residual: 0.0, ..Default::default() };
        let mut w = GraspWatch::default();
        for t in 0..1000 {
            assert!(w.observe(&p, tick(t, true, Some(1.0))).is_none());
        }
    }
}
