//! Where robots stand around the object: pure floor geometry, no simulator.
//!
//! * `robot_model::spatial::facing_ring`: `n` floor poses on a circle around a centre, each facing
//!   it (the first at
//!   the circle's `-x` point; two robots are the paper's facing pair);
//! * [`around_object`]: a team around a box or beam, robots spaced along the object's vertical
//!   faces ([`FaceLayout`]: which faces, how many per face, spacing, standoff), each facing its
//!   face;
//! * [`Footprint`] and [`check_clearance`]: the floor a standing robot takes, and the refusal
//!   of robots that would stand in each other.
//!
//! The planner's own geometric types: [`ObjectBox`] (the object's box and pose) and
//! [`BasePlacement`] (a robot's base on the floor and the joints set apart from its standing
//! pose). Scenarios name each robot's floor pose (`base_xy`, `yaw`) or a [`FaceLayout`]; the
//! runner turns the floor poses into the simulator's world and its robots into
//! [`BasePlacement`]s for the planner.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use protocol::conventions::quat_from_wxyz;
use robot_model::Robot;
use thiserror::Error;

/// Why robots cannot stand where they are asked to.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlacementError {
    #[error("team layout: {0}")]
    Layout(String),
    #[error("{robot}: footprint: {reason}")]
    Footprint { robot: String, reason: String },
    #[error(
        "robots {first} and {second} would stand in each other (their footprints, feet plus \
         {margin} m, overlap): space them further apart",
        margin = FOOTPRINT_MARGIN
    )]
    Clearance { first: String, second: String },
}

/// The carried object as the planner sees it: a box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectBox {
    /// Edge lengths, m.
    pub size: [f64; 3],
    /// Centre, world, m.
    pub position: [f64; 3],
    /// `(w, x, y, z)`.
    pub orientation: [f64; 4],
}

/// A robot where it stands: its base on the floor and the joints whose positions replace its
/// standing configuration's (the arm once its hand is on the object).
#[derive(Debug, Clone, PartialEq)]
pub struct BasePlacement {
    /// Robot id.
    pub id: String,
    /// Base position in the world, m.
    pub base_position: [f64; 3],
    /// Base yaw about world z, rad.
    pub base_yaw: f64,
    /// Joint positions that replace the standing configuration's, by joint name.
    pub joint_overrides: BTreeMap<String, f64>,
}

/// A vertical face of a box, named by its outward normal in the object's frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Face {
    #[serde(rename = "+x")]
    PlusX,
    #[serde(rename = "-x")]
    MinusX,
    #[serde(rename = "+y")]
    PlusY,
    #[serde(rename = "-y")]
    MinusY,
}

impl std::fmt::Display for Face {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Face::PlusX => "+x",
            Face::MinusX => "-x",
            Face::PlusY => "+y",
            Face::MinusY => "-y",
        })
    }
}

impl Face {
    /// Outward normal (object frame) and the axis index along which the face extends
    /// horizontally.
    fn normal_and_tangent_axis(self) -> (Vector3<f64>, usize, usize) {
        match self {
            Face::PlusX => (Vector3::x(), 0, 1),
            Face::MinusX => (-Vector3::x(), 0, 1),
            Face::PlusY => (Vector3::y(), 1, 0),
            Face::MinusY => (-Vector3::y(), 1, 0),
        }
    }
}

/// How a team stands around an object: `per_face` robots on each of `faces` (in that order),
/// neighbours `spacing` apart along the face and centred on it, each base `standoff` from its
/// face (horizontally, from the face plane to the base), facing the face.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaceLayout {
    pub faces: Vec<Face>,
    pub per_face: usize,
    /// m between neighbouring bases along a face.
    #[serde(default)]
    pub spacing: f64,
    /// m from the face plane to each base (the default robot reaches a face 0.85 m away).
    #[serde(default = "default_standoff")]
    pub standoff: f64,
}

/// The distance from a face to the default robot's base in the paper's pair (1.15 m from a
/// 0.6 m cube's centre).
pub const DEFAULT_STANDOFF: f64 = 0.85;

fn default_standoff() -> f64 {
    DEFAULT_STANDOFF
}

/// Distance each end of a face keeps free of hand centres, m (a palm is 0.1 m wide).
pub const FACE_END_MARGIN: f64 = 0.06;

/// Floor poses `((x, y), yaw)` of a team laid out by `layout` around `object` (a box with a
/// vertical z axis; its yaw may be any). Robots come face by face, along each face in the
/// direction of `z x n`. An error when the layout is empty, repeats a face, does not fit on a
/// face (the hands would leave it) or is not finite.
pub fn around_object(
    object: &ObjectBox,
    layout: &FaceLayout,
) -> Result<Vec<([f64; 2], f64)>, PlacementError> {
    let bad = |why: String| Err(PlacementError::Layout(why));
    if layout.faces.is_empty() || layout.per_face == 0 {
        return bad("needs at least one face and one robot per face".into());
    }
    if !(layout.spacing.is_finite()
        && layout.spacing >= 0.0
        && layout.standoff.is_finite()
        && layout.standoff > 0.0)
    {
        return bad(format!(
            "spacing {} must be >= 0 and standoff {} > 0, both finite",
            layout.spacing, layout.standoff
        ));
    }
    if layout.per_face > 1 && layout.spacing == 0.0 {
        return bad(format!("{} robots per face need a spacing", layout.per_face));
    }
    for (i, f) in layout.faces.iter().enumerate() {
        if layout.faces[..i].contains(f) {
            return bad(format!("face {f} named twice"));
        }
    }
    let rot = quat_from_wxyz(object.orientation);
    if (rot * Vector3::z()).z < 1.0 - 1e-9 {
        return bad("the object's z axis must be vertical to stand robots at its faces".into());
    }
    let centre = Vector3::from(object.position);
    let mut out = Vec::new();
    for face in &layout.faces {
        let (n_local, normal_axis, tangent_axis) = face.normal_and_tangent_axis();
        let n = rot * n_local;
        let t = Vector3::z().cross(&n);
        let half_length = object.size[tangent_axis] / 2.0;
        let span = layout.spacing * (layout.per_face - 1) as f64 / 2.0;
        if span > half_length - FACE_END_MARGIN {
            return bad(format!(
                "{} robots {} m apart span {:.3} m, face {face} is {:.3} m long (hands need \
                 {FACE_END_MARGIN} m from each end)",
                layout.per_face,
                layout.spacing,
                2.0 * span,
                2.0 * half_length
            ));
        }
        for k in 0..layout.per_face {
            let along = k as f64 * layout.spacing - span;
            let base = centre + n * (object.size[normal_axis] / 2.0 + layout.standoff) + t * along;
            out.push(([base.x, base.y], (-n.y).atan2(-n.x)));
        }
    }
    Ok(out)
}

/// How much room a standing robot takes on the floor: the rectangle (in its base frame, x
/// forward, y left) around its feet at the standing pose, widened by [`FOOTPRINT_MARGIN`] on
/// every side for the legs' and feet's own size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    pub min: [f64; 2],
    pub max: [f64; 2],
}

/// Added around the feet: a foot's radius (0.03 m) and a little clearance, m.
pub const FOOTPRINT_MARGIN: f64 = 0.04;

impl Footprint {
    /// The footprint of `robot` standing (feet from forward kinematics at its standing pose).
    pub fn of(robot: &Robot) -> Result<Self, PlacementError> {
        let invalid =
            |reason: String| PlacementError::Footprint { robot: robot.name.clone(), reason };
        let model = &robot.model;
        let mut data = robot_model::Data::new(model);
        let q: Vec<f64> = robot.standing_q.iter().copied().collect();
        robot_model::forward_kinematics(model, &mut data, &q, &vec![0.0; model.nv])
            .map_err(|e| invalid(e.to_string()))?;
        let torso = model.frame_id(&robot.torso_frame).map_err(|e| invalid(e.to_string()))?;
        let base = data.o_m_f[torso];
        let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for foot in &robot.foot_frames {
            let f = model.frame_id(foot).map_err(|e| invalid(e.to_string()))?;
            let p = base.rot.transpose() * (data.o_m_f[f].trans - base.trans);
            for k in 0..2 {
                min[k] = min[k].min(p[k] - FOOTPRINT_MARGIN);
                max[k] = max[k].max(p[k] + FOOTPRINT_MARGIN);
            }
        }
        if !(min.iter().chain(&max).all(|x| x.is_finite())) {
            return Err(invalid("a robot without feet has no footprint".into()));
        }
        Ok(Footprint { min, max })
    }

    /// The rectangle's corners on the floor for a base at `xy` facing `yaw`.
    fn corners(&self, xy: [f64; 2], yaw: f64) -> [[f64; 2]; 4] {
        let (c, s) = (yaw.cos(), yaw.sin());
        let at = |x: f64, y: f64| [xy[0] + c * x - s * y, xy[1] + s * x + c * y];
        [
            at(self.min[0], self.min[1]),
            at(self.max[0], self.min[1]),
            at(self.max[0], self.max[1]),
            at(self.min[0], self.max[1]),
        ]
    }
}

/// Whether two convex quadrilaterals overlap (separating-axis test on their edge normals).
fn overlap(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4]) -> bool {
    for poly in [a, b] {
        for i in 0..4 {
            let (p, q) = (poly[i], poly[(i + 1) % 4]);
            let axis = [q[1] - p[1], p[0] - q[0]];
            let project = |r: &[[f64; 2]; 4]| {
                r.iter()
                    .map(|v| v[0] * axis[0] + v[1] * axis[1])
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)))
            };
            let ((alo, ahi), (blo, bhi)) = (project(a), project(b));
            if ahi < blo || bhi < alo {
                return false;
            }
        }
    }
    true
}

/// Refuse placements whose robots would stand in each other: the footprints of every pair
/// (robot `i` at `placements[i]` with `footprints[i]`) must not overlap. The error names both.
pub fn check_clearance(
    placements: &[BasePlacement],
    footprints: &[Footprint],
) -> Result<(), PlacementError> {
    let corners: Vec<[[f64; 2]; 4]> = placements
        .iter()
        .zip(footprints)
        .map(|(p, f)| f.corners([p.base_position[0], p.base_position[1]], p.base_yaw))
        .collect();
    for i in 0..corners.len() {
        for j in i + 1..corners.len() {
            if overlap(&corners[i], &corners[j]) {
                return Err(PlacementError::Clearance {
                    first: placements[i].id.clone(),
                    second: placements[j].id.clone(),
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use robot_model::spatial::facing_ring;
    use std::f64::consts::PI;

    #[test]
    fn ring_poses_face_the_centre_at_the_radius() {
        for n in 2..=8 {
            let c = [0.3, -0.2];
            let poses = facing_ring(c, 1.15, n);
            assert_eq!(poses.len(), n);
            for (i, ([x, y], yaw)) in poses.iter().enumerate() {
                let (dx, dy) = (x - c[0], y - c[1]);
                assert!(
                    ((dx * dx + dy * dy).sqrt() - 1.15).abs() < 1e-12,
                    "robot {i} of {n} at the radius"
                );
                // Facing the centre: the heading points from the base to the centre.
                let (hx, hy) = (yaw.cos(), yaw.sin());
                assert!(
                    (hx * -dx + hy * -dy) / 1.15 > 1.0 - 1e-12,
                    "robot {i} of {n} faces the centre"
                );
                assert!(*yaw > -PI && *yaw <= PI + 1e-12);
            }
        }
        // Two robots: the paper's pair, first on -x facing +x, second on +x facing -x.
        let pair = facing_ring([0.0, 0.0], 1.15, 2);
        assert!((pair[0].0[0] + 1.15).abs() < 1e-12 && pair[0].1.abs() < 1e-12);
        assert!((pair[1].0[0] - 1.15).abs() < 1e-12 && (pair[1].1.abs() - PI).abs() < 1e-12);
        assert_eq!(facing_ring([1.0, 2.0], 5.0, 1), vec![([1.0, 2.0], 0.0)]);
    }

    fn beam() -> ObjectBox {
        ObjectBox {
            size: [2.4, 0.4, 0.4],
            position: [1.0, 2.0, 0.6],
            orientation: [1.0, 0.0, 0.0, 0.0],
        }
    }

    /// Each base at the standoff from its face plane, facing it, spaced along the face and
    /// centred on it; written out in world coordinates for a beam and a yawed cube.
    #[test]
    fn robots_stand_at_their_faces_facing_them() {
        let layout = FaceLayout {
            faces: vec![Face::MinusY, Face::PlusY],
            per_face: 4,
            spacing: 0.6,
            standoff: 0.85,
        };
        let poses = around_object(&beam(), &layout).unwrap();
        assert_eq!(poses.len(), 8);
        for (i, ([x, y], yaw)) in poses.iter().enumerate() {
            let side = if i < 4 { -1.0 } else { 1.0 };
            assert!((y - (2.0 + side * (0.2 + 0.85))).abs() < 1e-12, "robot {i} y {y}");
            assert!(
                (yaw.sin() + side).abs() < 1e-12 && yaw.cos().abs() < 1e-12,
                "robot {i} faces the beam: yaw {yaw}"
            );
            assert!(x - 1.0 >= -0.9 - 1e-12 && x - 1.0 <= 0.9 + 1e-12);
        }
        let xs: Vec<f64> = poses[..4].iter().map(|p| p.0[0]).collect();
        let mean = xs.iter().sum::<f64>() / 4.0;
        assert!((mean - 1.0).abs() < 1e-12, "centred on the face");
        let mut sorted = xs.clone();
        sorted.sort_by(f64::total_cmp);
        for w in sorted.windows(2) {
            assert!((w[1] - w[0] - 0.6).abs() < 1e-12, "spacing {:?}", w);
        }
        // A cube yawed by 30 deg: the base of the +x face lies on the rotated x axis.
        let yaw = 30f64.to_radians();
        let cube = ObjectBox {
            size: [0.6; 3],
            position: [0.0, 0.0, 0.6],
            orientation: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()],
        };
        let one = around_object(
            &cube,
            &FaceLayout { faces: vec![Face::PlusX], per_face: 1, spacing: 0.0, standoff: 0.85 },
        )
        .unwrap();
        let ([x, y], heading) = one[0];
        assert!((x - 1.15 * yaw.cos()).abs() < 1e-12 && (y - 1.15 * yaw.sin()).abs() < 1e-12);
        assert!((heading - (yaw - PI)).abs() < 1e-12 || (heading - (yaw + PI)).abs() < 1e-12);
    }

    #[test]
    fn layouts_that_cannot_be_stood_are_refused() {
        let ok = FaceLayout {
            faces: vec![Face::MinusY, Face::PlusY],
            per_face: 3,
            spacing: 0.8,
            standoff: 0.85,
        };
        assert!(around_object(&beam(), &ok).is_ok());
        for bad in [
            FaceLayout { per_face: 5, ..ok.clone() }, // 3.2 m on a 2.4 m face
            FaceLayout { faces: vec![], ..ok.clone() },
            FaceLayout { per_face: 0, ..ok.clone() },
            FaceLayout { spacing: 0.0, ..ok.clone() },
            FaceLayout { standoff: f64::NAN, ..ok.clone() },
            FaceLayout { faces: vec![Face::PlusX, Face::PlusX], per_face: 1, ..ok.clone() },
            // 0.8 m on a 0.4 m end
            FaceLayout { faces: vec![Face::PlusX], per_face: 2, ..ok.clone() },
        ] {
            let e = around_object(&beam(), &bad).expect_err(&format!("{bad:?}")).to_string();
            assert!(e.contains("team layout"), "{e}");
        }
    }

    /// The default robot's footprint holds its feet; two robots side by side clear at 0.7 m and
    /// not at 0.6 m (eight robots on the beam at 0.6 m stood in each other and fell); a robot
    /// turned 90 deg is checked on its rotated rectangle.
    #[test]
    fn footprints_of_neighbours_must_not_overlap() {
        let robot = Robot::load(robot_model::default_robot_path()).unwrap();
        let f = Footprint::of(&robot).unwrap();
        assert!(f.max[0] > 0.3 && f.min[0] < -0.3, "feet fore and aft of the base: {f:?}");
        let width = f.max[1] - f.min[1];
        assert!(
            width > 0.6 && width < 0.7,
            "side by side the robots need between 0.6 and 0.7 m: width {width}"
        );
        let at = |id: &str, x: f64, yaw: f64| BasePlacement {
            id: id.into(),
            base_position: [x, 0.0, 0.54882015],
            base_yaw: yaw,
            joint_overrides: BTreeMap::new(),
        };
        let pair = |d: f64, yaw_b: f64| vec![at("a", 0.0, PI / 2.0), at("b", d, yaw_b)];
        assert!(check_clearance(&pair(0.7, PI / 2.0), &[f, f]).is_ok());
        let e = check_clearance(&pair(0.6, PI / 2.0), &[f, f]).unwrap_err().to_string();
        assert!(e.contains("robots a and b"), "{e}");
        // b turned to face along x: its long side reaches towards a.
        assert!(check_clearance(&pair(0.7, 0.0), &[f, f]).is_err());
        assert!(check_clearance(&pair(1.2, 0.0), &[f, f]).is_ok());
    }
}
