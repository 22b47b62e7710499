//! Ground truth from MuJoCo, for evaluation only (the controller never reads it): object pose
//! and twist, torso poses and twists, hand-object contact points and wrenches, foot contact
//! wrenches ([`protocol::GroundTruth`]). Computed after a step (the contact forces are those of
//! the last physics step), published on `team/{team}/ground-truth` and recorded in memory, with
//! a CSV summary for reports.

use std::io::Write;

use mujoco_rs::mujoco_c::{self, mjData, mjModel, mjtObj};
use protocol::{BodyTruth, ContactTruth, GroundTruth, Header, Pose};

use crate::world::{id2name, World};

/// Pose and world-frame twist `[v; omega]` of a body's frame (MuJoCo's `xpos`/`xquat` and
/// `mj_objectVelocity` on `mjOBJ_XBODY` in world coordinates).
fn body_truth(m: &mjModel, d: &mjData, body: usize, name: &str) -> BodyTruth {
    let mut pose = Pose::IDENTITY;
    let mut vel = [0.0; 6];
    unsafe {
        for k in 0..3 {
            pose.position[k] = *d.xpos.add(3 * body + k);
        }
        for k in 0..4 {
            pose.orientation[k] = *d.xquat.add(4 * body + k);
        }
        mujoco_c::mj_objectVelocity(m, d, mjtObj::mjOBJ_XBODY as i32, body as i32, &mut vel, 0);
    }
    let n = pose.orientation.iter().map(|x| x * x).sum::<f64>().sqrt();
    pose.orientation.iter_mut().for_each(|x| *x /= n);
    // mj_objectVelocity gives [angular; linear]; ours is [linear; angular].
    BodyTruth {
        name: name.to_string(),
        pose,
        twist: [vel[3], vel[4], vel[5], vel[0], vel[1], vel[2]],
    }
}

/// Position and world-frame twist `[v; omega]` of a geom's centre (a foot sphere), world-aligned.
fn geom_truth(m: &mjModel, d: &mjData, geom: usize, name: &str) -> BodyTruth {
    let mut pose = Pose::IDENTITY;
    let mut vel = [0.0; 6];
    unsafe {
        for k in 0..3 {
            pose.position[k] = *d.geom_xpos.add(3 * geom + k);
        }
        mujoco_c::mj_objectVelocity(m, d, mjtObj::mjOBJ_GEOM as i32, geom as i32, &mut vel, 0);
    }
    BodyTruth {
        name: name.to_string(),
        pose,
        twist: [vel[3], vel[4], vel[5], vel[0], vel[1], vel[2]],
    }
}

/// Ground truth of the current MuJoCo state (call after `mj_step` or `mj_forward`).
pub fn compute(world: &World, d: &mjData, team: &str, tick: u64, out: &mut GroundTruth) {
    let m = world.model.ffi();
    out.header = Header::new(team, None, tick, protocol::wall_clock_ns());
    out.time = d.time;
    out.object = world.object.map(|(b, _, _)| body_truth(m, d, b, "object"));
    robot_body_truths(world, m, d, out);
    contact_truths(world, m, d, out);
}

/// Torso, hand and foot states of every robot.
fn robot_body_truths(world: &World, m: &mjModel, d: &mjData, out: &mut GroundTruth) {
    out.torsos.clear();
    out.hands.clear();
    out.feet.clear();
    for r in &world.robots {
        out.torsos.push(body_truth(m, d, r.base_body, &r.id));
        out.hands.push(body_truth(m, d, r.hand_contact_body, &r.id));
        for (frame, &body) in r.robot.foot_frames.iter().zip(&r.foot_bodies) {
            if let Some(&g) =
                r.foot_geoms.iter().find(|&&g| unsafe { *m.geom_bodyid.add(g) } as usize == body)
            {
                out.feet.push(geom_truth(m, d, g, &format!("{}/{frame}", r.id)));
            }
        }
    }
}

/// World-frame wrench `[f; tau]` of contact `i` (frame `c.frame`), acting on geom2 from geom1.
fn contact_wrench(m: &mjModel, d: &mjData, i: usize, c: &mujoco_c::mjContact) -> [f64; 6] {
    let mut f = [0.0; 6];
    unsafe { mujoco_c::mj_contactForce(m, d, i as i32, &mut f) };
    // Contact frame rows: normal, tangent 1, tangent 2; the force acts on geom2 from geom1.
    let fr = &c.frame;
    let mut w = [0.0; 6];
    for k in 0..3 {
        w[k] = fr[k] * f[0] + fr[3 + k] * f[1] + fr[6 + k] * f[2];
        w[3 + k] = fr[k] * f[3] + fr[3 + k] * f[4] + fr[6 + k] * f[5];
    }
    w
}

/// Hand-object and foot contacts of every robot, with the wrench each applies.
fn contact_truths(world: &World, m: &mjModel, d: &mjData, out: &mut GroundTruth) {
    out.hand_contacts.clear();
    out.foot_contacts.clear();
    let object_geom = world.object_geom.map(|g| g as i32);
    for i in 0..d.ncon as usize {
        let c = unsafe { &*d.contact.add(i) };
        let (g1, g2) = (c.geom[0], c.geom[1]);
        for r in &world.robots {
            let hand = r.hand_geoms.iter().any(|&g| g as i32 == g1 || g as i32 == g2);
            let foot = r.foot_geoms.iter().any(|&g| g as i32 == g1 || g as i32 == g2);
            if !(hand || foot) {
                continue;
            }
            let other = if r.hand_geoms.iter().chain(&r.foot_geoms).any(|&g| g as i32 == g1) {
                g2
            } else {
                g1
            };
            let robot_is_first = other == g2;
            let w = contact_wrench(m, d, i, c);
            let body = unsafe { *m.geom_bodyid.add(if robot_is_first { g1 } else { g2 } as usize) }
                as usize;
            let name = id2name(m, mjtObj::mjOBJ_BODY, body);
            let name = name.strip_prefix(&format!("{}/", r.id)).unwrap_or(&name).to_string();
            if hand && Some(other) == object_geom {
                // What the hand applies to the object.
                let s = if robot_is_first { 1.0 } else { -1.0 };
                out.hand_contacts.push(ContactTruth {
                    robot: r.id.clone(),
                    body: name,
                    position: c.pos,
                    wrench: w.map(|x| s * x),
                });
            } else if foot && !r.hand_geoms.iter().any(|&g| g as i32 == other) {
                // What the other body (the ground) applies to the foot.
                let s = if robot_is_first { -1.0 } else { 1.0 };
                out.foot_contacts.push(ContactTruth {
                    robot: r.id.clone(),
                    body: name,
                    position: c.pos,
                    wrench: w.map(|x| s * x),
                });
            }
        }
    }
}

/// An empty ground-truth message.
pub fn empty(team: &str) -> GroundTruth {
    GroundTruth {
        header: Header::new(team, None, 0, 0),
        time: 0.0,
        object: None,
        torsos: Vec::new(),
        hand_contacts: Vec::new(),
        foot_contacts: Vec::new(),
        hands: Vec::new(),
        feet: Vec::new(),
        loop_timing: Vec::new(),
    }
}

/// Ground truth kept in memory, every `every` ticks.
#[derive(Debug, Default, Clone)]
pub struct GroundTruthLog {
    pub every: u64,
    pub records: Vec<GroundTruth>,
}

impl GroundTruthLog {
    pub fn new(every: u64) -> Self {
        GroundTruthLog { every: every.max(1), records: Vec::new() }
    }

    pub fn offer(&mut self, gt: &GroundTruth) {
        if gt.header.tick % self.every == 0 {
            self.records.push(gt.clone());
        }
    }

    /// CSV summary: time, object pose, each torso's pose, per robot the summed hand force on
    /// the object and the summed foot forces (world frame).
    pub fn write_csv(&self, mut w: impl Write) -> std::io::Result<()> {
        let Some(first) = self.records.first() else { return Ok(()) };
        let mut head = vec!["tick".to_string(), "time".to_string()];
        for c in ["x", "y", "z", "qw", "qx", "qy", "qz"] {
            head.push(format!("object_{c}"));
        }
        for t in &first.torsos {
            for c in ["x", "y", "z", "qw", "qx", "qy", "qz"] {
                head.push(format!("{}_torso_{c}", t.name));
            }
            for c in ["fx", "fy", "fz"] {
                head.push(format!("{}_hand_{c}", t.name));
            }
            for c in ["fx", "fy", "fz"] {
                head.push(format!("{}_feet_{c}", t.name));
            }
        }
        writeln!(w, "{}", head.join(","))?;
        for g in &self.records {
            let mut row = vec![g.header.tick.to_string(), format!("{}", g.time)];
            let o = g.object.as_ref().map(|o| o.pose).unwrap_or(Pose::IDENTITY);
            row.extend(o.position.iter().chain(&o.orientation).map(|x| format!("{x}")));
            for t in &g.torsos {
                row.extend(
                    t.pose.position.iter().chain(&t.pose.orientation).map(|x| format!("{x}")),
                );
                let sum = |list: &[ContactTruth]| {
                    let mut s = [0.0; 3];
                    for c in list.iter().filter(|c| c.robot == t.name) {
                        for k in 0..3 {
                            s[k] += c.wrench[k];
                        }
                    }
                    s
                };
                row.extend(sum(&g.hand_contacts).iter().map(|x| format!("{x}")));
                row.extend(sum(&g.foot_contacts).iter().map(|x| format!("{x}")));
            }
            writeln!(w, "{}", row.join(","))?;
        }
        Ok(())
    }
}
