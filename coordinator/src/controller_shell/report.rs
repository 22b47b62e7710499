//! The tick's outputs every controller of the shell writes the same way, reusing the previous
//! tick's messages (their strings and vectors) when the team is the same: each robot's torque
//! slice ([`torque_commands_into`]) and the diagnostics' shared part ([`diagnostics_into`]:
//! the real contact wrenches, the solver's figures, the object estimate, the fallback taken).

use nalgebra::{DVector, UnitQuaternion};
use protocol::conventions::quat_to_wxyz;
use protocol::{ContactWrench, DynamicsTerms, Header, QpStatus, TickDiagnostics, TorqueCommand};

use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::messages::{set_header, set_note, set_string};
use crate::team::{RobotBlock, Team};

/// Each robot's torque command into `out`, its torques and accelerations written by `slice`
/// (which extends the cleared `tau` with the robot's actuated torques, in the order of its
/// robots, and the cleared `qdd` with what they accelerate its actuated joints by, or leaves it
/// empty).
pub fn torque_commands_into(
    team: &Team,
    tick: &[DynamicsTerms],
    out: &mut Vec<TorqueCommand>,
    mut slice: impl FnMut(&RobotBlock, &mut Vec<f64>, &mut Vec<f64>),
) {
    out.truncate(team.robots.len());
    for (k, (r, t)) in team.robots.iter().zip(tick).enumerate() {
        if k == out.len() {
            out.push(TorqueCommand {
                header: Header::new(&t.header.team, Some(&r.id), 0, 0),
                tau: Vec::new(),
                hold: false,
                delay_ticks: 0,
                qdd: Vec::new(),
            });
        }
        let cmd = &mut out[k];
        set_header(&mut cmd.header, &t.header.team, Some(&r.id), t.header.tick, 0);
        // The message may be last tick's hold order (the service reuses the buffer).
        cmd.hold = false;
        cmd.tau.clear();
        cmd.qdd.clear();
        slice(r, &mut cmd.tau, &mut cmd.qdd);
    }
}

/// What the diagnostics' shared part reads of a tick.
pub struct TickOutputs<'a> {
    pub team: &'a Team,
    pub grasp: Option<&'a GraspTerms>,
    /// The real contact wrenches, feet (3 rows each) then hands (6 rows each); frames past its
    /// end report zeros.
    pub wrench: &'a DVector<f64>,
    /// The contact-force solver's status and iterations.
    pub status: QpStatus,
    pub iterations: u32,
    /// Times of the solver, of the assembly, of the whole tick, µs.
    pub solve_us: f64,
    pub assembly_us: f64,
    pub total_us: f64,
    /// `|J_c v|`: the constraints' velocity, which a held contact keeps at zero.
    pub residual: f64,
    /// The fallback taken, or why the hands are free, if so.
    pub note: Option<&'a str>,
}

/// The diagnostics' shared part into `d`: header, real contact wrenches, the solver's figures,
/// `|J_c v|` (`f64::MAX` when not finite), the object estimate and the fit's slip, the note.
pub fn diagnostics_into(o: &TickOutputs, tick: &[DynamicsTerms], d: &mut TickDiagnostics) {
    let (team_id, tick_no) =
        tick.first().map_or(("", 0), |t| (t.header.team.as_str(), t.header.tick));
    set_header(&mut d.header, team_id, None, tick_no, protocol::wall_clock_ns());
    contact_wrenches_into(o.team, o.wrench, d);
    d.qp_status = o.status;
    d.qp_iterations = o.iterations;
    d.qp_solve_us = o.solve_us;
    d.assembly_us = o.assembly_us;
    d.total_us = o.total_us;
    d.constraint_residual = if o.residual.is_finite() { o.residual } else { f64::MAX };
    d.object_estimate = o.grasp.map(|g| protocol::Pose {
        position: g.object.translation.vector.into(),
        orientation: quat_to_wxyz(&UnitQuaternion::from_rotation_matrix(
            &g.object.rotation.to_rotation_matrix(),
        )),
    });
    d.grasp_slip = o.grasp.map_or(0.0, |g| g.fit_residual);
    d.grasp_refits = o.grasp.map_or(0, |g| g.refits);
    d.grasp_slip_since_closed = o.grasp.map_or(0.0, |g| g.slip_since_closed);
    set_note(&mut d.fallback, o.note);
}

/// Each contact frame's real wrench (feet 3 rows, hands 6) into `d.contacts`, named by robot
/// and frame.
fn contact_wrenches_into(team: &Team, wrench: &DVector<f64>, d: &mut TickDiagnostics) {
    let frames = team.feet.iter().map(|f| (f, 3)).chain(team.hands.iter().map(|h| (h, 6)));
    d.contacts.truncate(team.feet.len() + team.hands.len());
    let mut row = 0;
    for (k, (f, dim)) in frames.enumerate() {
        if k == d.contacts.len() {
            d.contacts.push(ContactWrench {
                robot: String::new(),
                frame: String::new(),
                wrench: Vec::new(),
            });
        }
        let c = &mut d.contacts[k];
        set_string(&mut c.robot, &team.robots[f.robot].id);
        set_string(&mut c.frame, &f.name);
        c.wrench.clear();
        if wrench.len() >= row + dim {
            c.wrench.extend(wrench.rows(row, dim).iter());
        } else {
            c.wrench.extend(std::iter::repeat_n(0.0, dim));
        }
        row += dim;
    }
}

/// A tick's diagnostic note: the release on the tick the team let go (its tick and cause are
/// the event of record), else the fallback taken, else the release in force.
pub fn tick_note<'a>(
    fallback: Option<&'a str>,
    release: Option<&'a str>,
    released_now: bool,
) -> Option<&'a str> {
    if released_now {
        release.or(fallback)
    } else {
        fallback.or(release)
    }
}

#[cfg(test)]
mod tests {
    use super::tick_note;

    #[test]
    fn the_release_is_named_on_its_tick_even_when_the_tick_fell_back() {
        let (fallback, release) =
            (Some("QP Infeasible: ..."), Some("grasp released at tick 7: ..."));
        assert_eq!(tick_note(fallback, release, true), release, "the release's own tick");
        assert_eq!(tick_note(fallback, release, false), fallback, "a later tick that fell back");
        assert_eq!(tick_note(None, release, false), release, "a later tick solved");
        assert_eq!(tick_note(fallback, None, false), fallback);
        assert_eq!(tick_note(None, None, false), None);
    }
}
