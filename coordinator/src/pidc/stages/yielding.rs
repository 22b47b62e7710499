//! The motion yields before the grasp is let go: when the contact-force QP (eq.
//! wrench_optim2) has no solution for the tick's motion, the controller gives up tracking
//! before it gives up the object.
//!
//! **The rule.** Every yielding task keeps a share `s` of its motion ([`MotionScale`]): at `s`
//! it commands `s (a_d - K_d edot - K_p e) - (1 - s) K_d v` (held still at `s = 0`: no
//! acceleration asked, its damping bringing it to rest where it is; see
//! [`TaskStack::joint_torque_yielding`]). The object's motion yields first, with the torsos
//! tracked whole; only when even the object held still is infeasible do the torsos yield too.
//! The tick is solved at the largest share that is feasible. A pose the team reached on the
//! way may be past what even holding still allows within the controller's margins (the
//! margins are a reserve, not the physics): then the object, and if need be everything, is
//! held still on the margins' reserve ([`ContactMargins::reserve`]: three quarters of the
//! palm, half the least squeeze). The grasp is let go ([`crate::building_blocks::release`]) only
//! when that is
//! infeasible too.
//!
//! [`ContactMargins::reserve`]: crate::building_blocks::contact_margins::ContactMargins::reserve
//!
//! **Why a share of the tick's task accelerations**, and not a time-scaling of the reference
//! or a strict hierarchy of QPs: `tau_M`, hence `tau_0 = [P S]^+ P tau_M`, the object's load
//! `J_x^T F_x` and the contact map's offset `eta`, are affine in each share, and the QP's
//! rows are linear in `(F_c, eta)`; the shares the QP accepts therefore form an interval, and
//! bisection on it is exact to its resolution ([`YIELD_STEPS`]). It costs nothing on a tick
//! the QP solves at the full motion, keeps the direction of every task's command, needs
//! neither the planner nor the references to change, and is the same rule for every task
//! (MQP's tasks are soft terms of its objective already: its motion yields by construction,
//! and its QP fails only when no motion at all keeps its constraints). The reference runs on
//! while the motion yields: the error grows while the contacts cannot carry it, and is made up
//! as soon as they can.

use nalgebra::{DVector, Vector6};

pub use crate::building_blocks::impedance::MotionScale;
use crate::linalg::zeros_v;

/// Bisection steps on a share: `2^-5` of the motion (about 3 %).
pub const YIELD_STEPS: u32 = 5;

/// The order in which the tasks yield: the object's motion first, the torsos' after it.
///
/// `feasible` sets the tick's motion to a scale and says whether the QP solved it; the tick
/// is left at the returned scale (the last call is at it), or, on `None` (even everything held
/// still is infeasible), at everything held still.
pub fn yield_motion(mut feasible: impl FnMut(MotionScale) -> bool) -> Option<MotionScale> {
    if feasible(MotionScale { object: 0.0, torso: 1.0, reserve: false }) {
        if let Some(s) =
            largest_share(|s| feasible(MotionScale { object: s, torso: 1.0, reserve: false }))
        {
            return Some(MotionScale { object: s, torso: 1.0, reserve: false });
        }
    }
    if feasible(MotionScale { object: 0.0, torso: 0.0, reserve: false }) {
        let s = largest_share(|s| feasible(MotionScale { object: 0.0, torso: s, reserve: false }))?;
        return Some(MotionScale { object: 0.0, torso: s, reserve: false });
    }
    None
}

/// The largest share in `[0, 1)` that `feasible` accepts, to `2^-YIELD_STEPS`, given that it
/// accepts 0 and refuses 1 (the interval of feasible shares, see the module docs); the last
/// call is at the share returned. `None` when the tick, solved again at that share, fails.
pub fn largest_share(mut feasible: impl FnMut(f64) -> bool) -> Option<f64> {
    let (mut lo, mut hi) = (0.0, 1.0);
    let mut at_lo = true;
    for _ in 0..YIELD_STEPS {
        let mid = 0.5 * (lo + hi);
        at_lo = feasible(mid);
        if at_lo {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (at_lo || feasible(lo)).then_some(lo)
}

/// What a motion scale changes in a tick: `tau_M`, `tau_0`, the object's load `J_x^T F_x` and
/// `F_x`.
#[derive(Debug, Clone, Default)]
pub struct TickMotion {
    pub tau_m: DVector<f64>,
    pub tau0: DVector<f64>,
    pub load: DVector<f64>,
    pub f_x: Vector6<f64>,
}

impl TickMotion {
    /// A copy of these quantities, reusing the buffers.
    pub fn copy_from(
        &mut self,
        tau_m: &DVector<f64>,
        tau0: &DVector<f64>,
        load: &DVector<f64>,
        f_x: &Vector6<f64>,
    ) {
        for (dst, src) in [(&mut self.tau_m, tau_m), (&mut self.tau0, tau0), (&mut self.load, load)]
        {
            zeros_v(dst, src.len());
            dst.copy_from(src);
        }
        self.f_x = *f_x;
    }

    /// These quantities back into the outputs.
    pub fn restore(
        &self,
        tau_m: &mut DVector<f64>,
        tau0: &mut DVector<f64>,
        load: &mut DVector<f64>,
        f_x: &mut Vector6<f64>,
    ) {
        for (dst, src) in [(tau_m, &self.tau_m), (tau0, &self.tau0), (load, &self.load)] {
            zeros_v(dst, src.len());
            dst.copy_from(src);
        }
        *f_x = self.f_x;
    }
}

/// The motions a yield blends between, kept between ticks so that a yield allocates nothing:
/// the tick's motion as commanded, with the object held still (torsos whole), and with
/// everything held still.
#[derive(Debug, Clone, Default)]
pub struct YieldScratch {
    pub full: TickMotion,
    pub object_still: TickMotion,
    pub all_still: TickMotion,
}

impl YieldScratch {
    /// The motion at `scale` (on the order of [`yield_motion`]: the object's share with the
    /// torsos whole, or the torsos' with the object still) into the outputs.
    pub fn blend_into(
        &self,
        scale: MotionScale,
        tau_m: &mut DVector<f64>,
        tau0: &mut DVector<f64>,
        load: &mut DVector<f64>,
        f_x: &mut Vector6<f64>,
    ) {
        if scale.torso >= 1.0 {
            blend(&self.object_still, &self.full, scale.object, tau_m, tau0, load, f_x);
        } else {
            blend(&self.all_still, &self.object_still, scale.torso, tau_m, tau0, load, f_x);
        }
    }
}

/// `out = still + s (moving - still)`, entry by entry (exact for the affine quantities of a
/// motion scale, see the module docs).
pub fn blend(
    still: &TickMotion,
    moving: &TickMotion,
    s: f64,
    tau_m: &mut DVector<f64>,
    tau0: &mut DVector<f64>,
    load: &mut DVector<f64>,
    f_x: &mut Vector6<f64>,
) {
    for (out, a, b) in [
        (tau_m, &still.tau_m, &moving.tau_m),
        (tau0, &still.tau0, &moving.tau0),
        (load, &still.load, &moving.load),
    ] {
        zeros_v(out, a.len());
        for i in 0..a.len() {
            out[i] = a[i] + s * (b[i] - a[i]);
        }
    }
    *f_x = still.f_x + s * (moving.f_x - still.f_x);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_share_is_found_to_the_resolution_and_left_in_place() {
        for limit in [0.0, 0.01, 0.3, 0.5, 0.77, 0.99] {
            let mut last = f64::NAN;
            let s = largest_share(|s| {
                last = s;
                s <= limit
            })
            .expect("the share found solves again");
            assert!(
                s <= limit && limit - s < 1.0 / f64::from(1u32 << YIELD_STEPS),
                "limit {limit}: share {s}"
            );
            assert_eq!(last, s, "the tick is left at the share found");
        }
    }

    #[test]
    fn the_object_yields_before_the_torsos() {
        // Feasible while the object keeps at most 40 % with the torsos whole.
        let ok = |m: MotionScale| m.object <= 0.4 && m.torso == 1.0;
        let y = yield_motion(ok).expect("feasible with the object yielding");
        assert_eq!(y.torso, 1.0);
        assert!((0.37..=0.4).contains(&y.object), "{y:?}");
        // Only with the object still and the torsos at most 60 %.
        let y = yield_motion(|m| m.object == 0.0 && m.torso <= 0.6)
            .expect("feasible with both yielding");
        assert_eq!(y.object, 0.0);
        assert!((0.57..=0.6).contains(&y.torso), "{y:?}");
        // Nothing is feasible: the last motion tried is everything held still.
        let mut last = None;
        assert!(yield_motion(|m| {
            last = Some(m);
            false
        })
        .is_none());
        assert_eq!(last, Some(MotionScale { object: 0.0, torso: 0.0, reserve: false }));
    }
}
