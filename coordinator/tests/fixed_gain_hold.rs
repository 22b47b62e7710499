//! A third controller on the controller shell: a fixed-gain joint hold, its law alone. The
//! shell ([`coordinator::Shell`]) gives it the descriptions, readiness, the terms' checks and
//! the rest of [`TeamController`].
mod common;

use std::collections::BTreeMap;

use common::{rng, robot_id, Fixture};
use coordinator::building_blocks::messages::set_header;
use coordinator::{ControlLaw, ControllerError, Shell, ShellState, TeamController};
use nalgebra::DVector;
use protocol::{DynamicsTerms, Header, TorqueCommand};
use rand::Rng;

/// `tau = h + K_p (q0 - q) - K_d v` on every actuated joint, clamped to its torque limit. The
/// terms carry no positions: `q - q0` is the integral of the joint velocities since the robot
/// was first seen (its `q0` latched there), one control period per tick.
struct FixedGainHold {
    kp: f64,
    kd: f64,
    dt: f64,
    /// `q - q0` of each robot's actuated joints, by id.
    drift: BTreeMap<String, Vec<f64>>,
}

impl ControlLaw for FixedGainHold {
    fn law_name(&self) -> &'static str {
        "fixed-gain joint hold"
    }

    fn control(
        &mut self,
        state: &mut ShellState,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        out.truncate(tick.len());
        for (k, t) in tick.iter().enumerate() {
            let id = t.header.robot_id();
            let d = state
                .descriptions
                .get(id)
                .ok_or_else(|| ControllerError::MissingDescription { robot: id.into() })?;
            if !self.drift.contains_key(id) {
                self.drift.insert(id.to_string(), vec![0.0; t.actuated()]);
            }
            let drift = self.drift.get_mut(id).expect("latched above");
            if k == out.len() {
                let header = Header::new(&t.header.team, Some(id), 0, 0);
                out.push(TorqueCommand {
                    header,
                    tau: Vec::new(),
                    hold: false,
                    delay_ticks: 0,
                    qdd: Vec::new(),
                });
            }
            let cmd = &mut out[k];
            set_header(&mut cmd.header, &t.header.team, Some(id), t.header.tick, 0);
            cmd.hold = false;
            cmd.tau.clear();
            let first = t.nv() - t.actuated();
            for (j, (e, lim)) in drift.iter_mut().zip(&d.torque_limits).enumerate() {
                let (h, v) = (t.bias[first + j], t.velocity[first + j]);
                cmd.tau.push((h - self.kp * *e - self.kd * v).clamp(-lim, *lim));
                *e += self.dt * v;
            }
        }
        Ok(())
    }
}

fn hold() -> Shell<FixedGainHold> {
    Shell::with_law(FixedGainHold { kp: 80.0, kd: 4.0, dt: 1e-3, drift: BTreeMap::new() })
}

#[test]
fn the_torque_is_the_law_written_out_on_two_ticks() {
    let mut fx = Fixture::new();
    let (_, descs) = fx.static_team(2);
    let mut c = hold();
    descs.iter().for_each(|d| c.set_description(d));
    let (nv, mut rng) = (fx.robot.model.nv, rng(7));
    let vs: Vec<DVector<f64>> =
        (0..2).map(|_| DVector::from_fn(nv, |_, _| rng.random_range(-0.5..0.5))).collect();
    let q = fx.standing_q(0, 2);
    let (mut out, mut drift) = (Vec::new(), vec![0.0; nv - 6]);
    for (n, v) in vs.iter().enumerate() {
        let tick = vec![fx.terms(&robot_id(0), &q, v, n as u64 + 1)];
        c.solve(&tick, &mut out).expect("solved");
        assert_eq!((out.len(), out[0].header.tick), (1, n as u64 + 1));
        assert_eq!(out[0].tau.len(), nv - 6);
        let (h, tv) = (&tick[0].bias, &tick[0].velocity);
        for j in 0..nv - 6 {
            // K_p (q0 - q) = -K_p drift.
            let lim = descs[0].torque_limits[j];
            let want = (h[6 + j] - 80.0 * drift[j] - 4.0 * tv[6 + j]).clamp(-lim, lim);
            assert_eq!(out[0].tau[j], want, "tick {n}, joint {j}");
            drift[j] += 1e-3 * tv[6 + j];
        }
    }
    assert!(vs[0].rows(6, nv - 6).norm() > 0.1, "the second tick's K_p term is not zero");
    assert_eq!(c.name(), "fixed-gain joint hold");
    assert!(!c.used_fallback() && c.diagnostics().is_none());
}

#[test]
fn the_shell_waits_for_descriptions_and_refuses_terms_that_do_not_fit() {
    let mut fx = Fixture::new();
    let (mut terms, descs) = fx.static_team(2);
    let members = [robot_id(0), robot_id(1)];
    let mut c = hold();
    assert!(c.not_ready(&members).is_some_and(|why| why.contains("r1") && why.contains("r2")));
    let mut out = Vec::new();
    assert_eq!(
        c.solve(&terms, &mut out),
        Err(ControllerError::MissingDescription { robot: robot_id(0) })
    );
    c.set_description(&descs[0]);
    assert!(c.ready("r1") && !c.ready("r2"));
    assert!(c.not_ready(&members).is_some_and(|why| !why.contains("r1") && why.contains("r2")));
    c.set_description(&descs[1]);
    assert_eq!(c.not_ready(&members), None);
    assert!(terms.iter().all(|t| c.check_terms(t).is_ok()));
    terms[1].bias.pop();
    assert!(matches!(c.check_terms(&terms[1]), Err(ControllerError::Dimension { .. })));
    let mut fewer = descs[0].clone();
    fewer.joint_names.pop();
    c.set_description(&fewer);
    assert!(matches!(c.check_terms(&terms[0]), Err(ControllerError::Dimension { .. })));
}
