//! The 3-D view of a recording, for Foxglove's 3-D panel: every [`super::SCENE_HZ`] of sim
//! time, the world pose of every link of every robot (`/tf`, `foxglove.FrameTransforms`,
//! computed from the robot's latest state through its model: `forward_kinematics`), and
//! `/scene` (`foxglove.SceneUpdate`): each robot as lines from every link to its parent, the
//! object as a box, every contact force as an arrow (2 mm per N).

use std::collections::BTreeMap;
use std::sync::Arc;

use foxglove::messages::{
    ArrowPrimitive, Color, CubePrimitive, FrameTransform, FrameTransforms, LinePrimitive, Point3,
    Pose as FPose, Quaternion, SceneEntity, SceneUpdate, Timestamp, Vector3 as FVector3,
};
use foxglove::{Channel, ChannelBuilder, Context, PartialMetadata};
use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use protocol::{BodyTruth, ContactTruth, GroundTruth, RobotState, RunClock};
use robot_model::{forward_kinematics, Data, Robot};

use super::RecordedMessage;
use scenario::plan::Plan;

/// Length of a contact force arrow per newton, m.
pub const ARROW_M_PER_N: f64 = 0.002;
/// The world frame of the 3-D view.
pub const WORLD: &str = "world";

/// Counts of the writer thread.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WriterCounts {
    pub messages: u64,
    pub failed: u64,
    /// Files a splitting recorder closed (`super::segments`).
    pub segments: u64,
}

struct RobotView {
    robot: Arc<Robot>,
    data: Data,
    q: Vec<f64>,
    v: Vec<f64>,
    has_state: bool,
}

/// Builds `/tf` and `/scene` from the states and the ground truth.
pub struct SceneBuilder {
    clock: RunClock,
    every: u64,
    object_size: Option<[f64; 3]>,
    robots: BTreeMap<String, RobotView>,
    channels: Option<(Channel<FrameTransforms>, Channel<SceneUpdate>)>,
}

impl SceneBuilder {
    pub fn new(plan: &Plan) -> SceneBuilder {
        let robots = plan
            .robots
            .iter()
            .map(|r| {
                let m = &r.robot.model;
                let view = RobotView {
                    robot: r.robot.clone(),
                    data: Data::new(m),
                    q: vec![0.0; m.nq],
                    v: vec![0.0; m.nv],
                    has_state: false,
                };
                (r.id.clone(), view)
            })
            .collect();
        let clock = plan.references.clock;
        SceneBuilder {
            clock,
            every: clock.ticks_per_sample(super::SCENE_HZ),
            object_size: plan.scene.world.object.as_ref().map(|o| o.size),
            robots,
            channels: None,
        }
    }

    /// The log time of a message: its tick in sim time, ns.
    pub fn log_time(&self, message: &RecordedMessage) -> u64 {
        let h = match message {
            RecordedMessage::State(m) => &m.header,
            RecordedMessage::Dynamics(m) => &m.header,
            RecordedMessage::Command(m) => &m.header,
            RecordedMessage::Torque(m) => &m.header,
            RecordedMessage::Contacts(m) => &m.header,
            RecordedMessage::AgentStatus(m) => &m.header,
            RecordedMessage::Truth(m) => &m.header,
            RecordedMessage::Diagnostics(m) => &m.header,
            RecordedMessage::Status(m) => &m.header,
            RecordedMessage::References(m) => &m.header,
        };
        self.clock.run_time_ns(h.tick)
    }

    /// Keep states; on the ground truth of every `every`-th tick, log the view.
    pub fn observe(&mut self, ctx: &Arc<Context>, message: &RecordedMessage, log_time: u64) {
        match message {
            RecordedMessage::State(s) => self.take_state(s),
            RecordedMessage::Truth(g) if g.header.tick % self.every == 0 => {
                self.log_view(ctx, g, log_time)
            }
            _ => {}
        }
    }

    fn take_state(&mut self, s: &RobotState) {
        let Some(r) = s.header.robot.as_ref().and_then(|id| self.robots.get_mut(id)) else {
            return;
        };
        let m = &r.robot.model;
        let base = if m.floating_base { 7 } else { 0 };
        if s.joint_positions.len() + base != m.nq {
            return;
        }
        if m.floating_base {
            r.q[0..3].copy_from_slice(&s.base_pose.position);
            r.q[3..7].copy_from_slice(&s.base_pose.orientation);
        }
        r.q[base..].copy_from_slice(&s.joint_positions);
        r.has_state = true;
    }

    fn log_view(&mut self, ctx: &Arc<Context>, g: &GroundTruth, log_time: u64) {
        let (tf, scene) = self.channels.get_or_insert_with(|| {
            (
                ChannelBuilder::new("/tf").context(ctx).build(),
                ChannelBuilder::new("/scene").context(ctx).build(),
            )
        });
        let stamp =
            Timestamp::new((log_time / 1_000_000_000) as u32, (log_time % 1_000_000_000) as u32);
        let mut transforms = Vec::new();
        let mut entities = Vec::new();
        for (id, r) in &mut self.robots {
            if !r.has_state || forward_kinematics(&r.robot.model, &mut r.data, &r.q, &r.v).is_err()
            {
                continue;
            }
            entities.push(skeleton(id, r, stamp, &mut transforms));
        }
        if let (Some(o), Some(size)) = (&g.object, self.object_size) {
            entities.push(object_entity(o, size, stamp));
        }
        entities.push(contact_forces(g, stamp));
        let meta = PartialMetadata { log_time: Some(log_time) };
        tf.log_with_meta(&FrameTransforms { transforms }, meta);
        scene.log_with_meta(&SceneUpdate { deletions: Vec::new(), entities }, meta);
    }
}

/// Robot `id`'s skeleton (a line from each body to its parent) as of its last forward
/// kinematics; each body's frame goes to `transforms`.
fn skeleton(
    id: &str,
    r: &RobotView,
    stamp: Timestamp,
    transforms: &mut Vec<FrameTransform>,
) -> SceneEntity {
    let mut points = Vec::new();
    for (b, body) in r.robot.model.bodies.iter().enumerate() {
        let x = &r.data.o_m_i[b];
        let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(x.rot));
        transforms.push(FrameTransform {
            timestamp: Some(stamp),
            parent_frame_id: WORLD.into(),
            child_frame_id: format!("{id}/{}", body.name),
            translation: Some(vec3(&x.trans)),
            rotation: Some(quat(&q)),
        });
        if let Some(p) = body.parent {
            points.push(point(&r.data.o_m_i[p].trans));
            points.push(point(&x.trans));
        }
    }
    let line = LinePrimitive {
        r#type: 2,
        thickness: 0.02,
        points,
        color: Some(rgba(0.2, 0.4, 0.8, 1.0)),
        pose: Some(identity()),
        ..Default::default()
    };
    SceneEntity {
        timestamp: Some(stamp),
        frame_id: WORLD.into(),
        id: format!("robot/{id}"),
        lines: vec![line],
        ..Default::default()
    }
}

/// The object as a box of `size` at its true pose.
fn object_entity(o: &BodyTruth, size: [f64; 3], stamp: Timestamp) -> SceneEntity {
    let q = protocol::conventions::quat_from_wxyz(o.pose.orientation);
    let cube = CubePrimitive {
        pose: Some(FPose {
            position: Some(vec3(&Vector3::from(o.pose.position))),
            orientation: Some(quat(&q)),
        }),
        size: Some(FVector3 { x: size[0], y: size[1], z: size[2] }),
        color: Some(rgba(0.9, 0.6, 0.1, 0.8)),
    };
    SceneEntity {
        timestamp: Some(stamp),
        frame_id: WORLD.into(),
        id: "object".into(),
        cubes: vec![cube],
        ..Default::default()
    }
}

/// The hands' (red) and feet's (green) contact forces as arrows.
fn contact_forces(g: &GroundTruth, stamp: Timestamp) -> SceneEntity {
    let arrows: Vec<ArrowPrimitive> = g
        .hand_contacts
        .iter()
        .map(|c| arrow(c, rgba(0.85, 0.1, 0.1, 1.0)))
        .chain(g.foot_contacts.iter().map(|c| arrow(c, rgba(0.1, 0.6, 0.1, 1.0))))
        .flatten()
        .collect();
    SceneEntity {
        timestamp: Some(stamp),
        frame_id: WORLD.into(),
        id: "contact-forces".into(),
        arrows,
        ..Default::default()
    }
}

/// A contact force as an arrow from the contact point along the force (none below 0.1 N).
fn arrow(c: &ContactTruth, color: Color) -> Option<ArrowPrimitive> {
    let f = Vector3::new(c.wrench[0], c.wrench[1], c.wrench[2]);
    let n = f.norm();
    if n < 0.1 {
        return None;
    }
    // The arrow points along its pose's x axis.
    let q = UnitQuaternion::rotation_between(&Vector3::x(), &f).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
    });
    let len = n * ARROW_M_PER_N;
    Some(ArrowPrimitive {
        pose: Some(FPose {
            position: Some(vec3(&Vector3::from(c.position))),
            orientation: Some(quat(&q)),
        }),
        shaft_length: len * 0.8,
        shaft_diameter: 0.01,
        head_length: len * 0.2,
        head_diameter: 0.025,
        color: Some(color),
    })
}

fn vec3(v: &Vector3<f64>) -> FVector3 {
    FVector3 { x: v.x, y: v.y, z: v.z }
}

fn point(v: &Vector3<f64>) -> Point3 {
    Point3 { x: v.x, y: v.y, z: v.z }
}

fn quat(q: &UnitQuaternion<f64>) -> Quaternion {
    Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
}

fn identity() -> FPose {
    FPose {
        position: Some(FVector3 { x: 0.0, y: 0.0, z: 0.0 }),
        orientation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
    }
}

fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}
