//! URDF -> [`Model`]: tree checks, merging of fixed joints, composition (`attach`).
//!
//! Only `<link>`/`<inertial>` and `<joint>` elements are used: visual and collision geometry
//! (and therefore mesh files) are never opened, so a URDF whose meshes are missing loads.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::error::ModelError;
use crate::model::{Body, FloatingBase, Frame, FrameId, FrameKind, JointType, Model, GRAVITY};
use crate::spatial::{Inertia, SE3};

#[derive(Debug, Clone, Copy, PartialEq)]
enum JointKind {
    Fixed,
    Revolute,
    Continuous,
    Prismatic,
}

#[derive(Debug, Clone)]
struct LinkDesc {
    name: String,
    /// Inertia in the link frame.
    inertia: Inertia,
}

#[derive(Debug, Clone)]
struct JointDesc {
    name: String,
    kind: JointKind,
    parent: usize,
    child: usize,
    origin: SE3,
    axis: Vector3<f64>,
    lower: f64,
    upper: f64,
    effort: f64,
    velocity: f64,
}

/// A checked kinematic tree (links and joints), from one URDF or several attached ones.
/// Build the [`Model`] with [`ModelBuilder::build`].
#[derive(Debug, Clone)]
pub struct ModelBuilder {
    name: String,
    links: Vec<LinkDesc>,
    joints: Vec<JointDesc>,
    root: usize,
}

impl Model {
    /// Parses URDF text into a model.
    pub fn from_urdf_str(urdf: &str, floating: FloatingBase) -> Result<Model, ModelError> {
        ModelBuilder::from_urdf_str(urdf)?.build(floating)
    }

    /// Reads a URDF file into a model. Mesh files referenced by the URDF are not opened.
    pub fn from_urdf_file(
        path: impl AsRef<Path>,
        floating: FloatingBase,
    ) -> Result<Model, ModelError> {
        ModelBuilder::from_urdf_file(path)?.build(floating)
    }
}

fn finite(x: f64, what: impl FnOnce() -> String) -> Result<f64, ModelError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(ModelError::BadNumber { what: what(), detail: format!("{x} is not finite") })
    }
}

fn pose_to_se3(p: &urdf_rs::Pose, what: &str) -> Result<SE3, ModelError> {
    for (i, x) in p.xyz.0.iter().chain(p.rpy.0.iter()).enumerate() {
        finite(*x, || format!("{what} origin (component {i})"))?;
    }
    Ok(SE3::from_xyz_rpy(p.xyz.0, p.rpy.0))
}

/// The URDF's links with their inertias, and each link's index by name (names unique).
fn link_descs(
    robot: &urdf_rs::Robot,
) -> Result<(Vec<LinkDesc>, HashMap<String, usize>), ModelError> {
    let mut link_index = HashMap::new();
    let mut links = Vec::with_capacity(robot.links.len());
    for (i, l) in robot.links.iter().enumerate() {
        if link_index.insert(l.name.clone(), i).is_some() {
            return Err(ModelError::DuplicateName { kind: "link", name: l.name.clone() });
        }
        links.push(LinkDesc { name: l.name.clone(), inertia: link_inertia(l)? });
    }
    Ok((links, link_index))
}

/// One URDF joint, checked: its links known, its type supported, its origin, axis and limits
/// valid numbers.
fn joint_desc(
    j: &urdf_rs::Joint,
    link_index: &HashMap<String, usize>,
) -> Result<JointDesc, ModelError> {
    let find = |name: &str, role: &'static str| {
        link_index.get(name).copied().ok_or_else(|| ModelError::UnknownParent {
            joint: j.name.clone(),
            role,
            link: name.to_string(),
        })
    };
    let parent = find(&j.parent.link, "parent")?;
    let child = find(&j.child.link, "child")?;
    let kind = joint_kind(j)?;
    let origin = pose_to_se3(&j.origin, &format!("joint {:?}", j.name))?;
    let axis = joint_axis(j, kind)?;
    let (lower, upper, velocity) = joint_limits(j, kind)?;
    Ok(JointDesc {
        name: j.name.clone(),
        kind,
        parent,
        child,
        origin,
        axis,
        lower,
        upper,
        effort: j.limit.effort,
        velocity,
    })
}

/// The kind of a URDF joint; floating and planar joints are not supported.
fn joint_kind(j: &urdf_rs::Joint) -> Result<JointKind, ModelError> {
    Ok(match j.joint_type {
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        urdf_rs::JointType::Revolute => JointKind::Revolute,
        urdf_rs::JointType::Continuous => JointKind::Continuous,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        ref other => {
            return Err(ModelError::UnsupportedJoint {
                joint: j.name.clone(),
                kind: format!("{other:?}").to_lowercase(),
            })
        }
    })
}

/// The joint's axis, finite, and normalized unless the joint is fixed.
fn joint_axis(j: &urdf_rs::Joint, kind: JointKind) -> Result<Vector3<f64>, ModelError> {
    let mut axis = Vector3::from(j.axis.xyz.0);
    for (i, x) in axis.iter().enumerate() {
        finite(*x, || format!("joint {:?} axis (component {i})", j.name))?;
    }
    if kind != JointKind::Fixed {
        let n = axis.norm();
        if n < 1e-12 {
            return Err(ModelError::BadNumber {
                what: format!("joint {:?} axis", j.name),
                detail: "zero vector".into(),
            });
        }
        axis /= n;
    }
    Ok(axis)
}

/// The joint's position limits (none for a continuous joint) and velocity limit, checked.
fn joint_limits(j: &urdf_rs::Joint, kind: JointKind) -> Result<(f64, f64, f64), ModelError> {
    let lim = &j.limit;
    for (name, x) in [
        ("lower", lim.lower),
        ("upper", lim.upper),
        ("effort", lim.effort),
        ("velocity", lim.velocity),
    ] {
        if x.is_nan() {
            return Err(ModelError::BadNumber {
                what: format!("joint {:?} limit {name}", j.name),
                detail: "NaN".into(),
            });
        }
    }
    if lim.effort < 0.0 || lim.velocity < 0.0 {
        return Err(ModelError::BadNumber {
            what: format!("joint {:?} limit", j.name),
            detail: "negative effort or velocity limit".into(),
        });
    }
    let (lower, upper) = match kind {
        JointKind::Continuous => (f64::NEG_INFINITY, f64::INFINITY),
        _ => (lim.lower, lim.upper),
    };
    if lower > upper {
        return Err(ModelError::BadNumber {
            what: format!("joint {:?} limit", j.name),
            detail: format!("lower {lower} > upper {upper}"),
        });
    }
    // URDF 1.0 leaves the velocity limit at 0 when <limit> is absent: treat as unlimited
    let velocity = if lim.velocity > 0.0 { lim.velocity } else { f64::INFINITY };
    Ok((lower, upper, velocity))
}

impl ModelBuilder {
    pub fn from_urdf_file(path: impl AsRef<Path>) -> Result<Self, ModelError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .map_err(|source| ModelError::Io { path: path.display().to_string(), source })?;
        Self::from_urdf_str(&text)
    }

    pub fn from_urdf_str(urdf: &str) -> Result<Self, ModelError> {
        let urdf = super::urdf_filter::dynamics_only(urdf)?;
        let robot =
            urdf_rs::read_from_string(&urdf).map_err(|e| ModelError::Urdf(e.to_string()))?;
        Self::from_robot(&robot)
    }

    fn from_robot(robot: &urdf_rs::Robot) -> Result<Self, ModelError> {
        if robot.links.is_empty() {
            return Err(ModelError::Empty);
        }
        let (links, link_index) = link_descs(robot)?;
        let mut joints = Vec::with_capacity(robot.joints.len());
        let mut joint_names = HashMap::new();
        for j in &robot.joints {
            if joint_names.insert(j.name.clone(), ()).is_some() {
                return Err(ModelError::DuplicateName { kind: "joint", name: j.name.clone() });
            }
            joints.push(joint_desc(j, &link_index)?);
        }
        let root = check_tree(&links, &joints)?;
        Ok(Self { name: robot.name.clone(), links, joints, root })
    }

    /// Attaches another URDF (e.g. an arm) rigidly to the link `at` of this tree, at `pose`
    /// (`at` frame -> attached root link), prefixing every link and joint name of the attached
    /// tree with `prefix`. The attaching fixed joint is named `{prefix}attach_joint`.
    pub fn attach(
        mut self,
        other: ModelBuilder,
        at: &str,
        pose: SE3,
        prefix: &str,
    ) -> Result<Self, ModelError> {
        let at_idx = self
            .links
            .iter()
            .position(|l| l.name == at)
            .ok_or_else(|| ModelError::UnknownFrame { name: at.to_string() })?;
        let offset = self.links.len();
        for l in &other.links {
            let name = format!("{prefix}{}", l.name);
            if self.links.iter().any(|x| x.name == name) {
                return Err(ModelError::DuplicateName { kind: "link", name });
            }
            self.links.push(LinkDesc { name, inertia: l.inertia });
        }
        let attach_name = format!("{prefix}attach_joint");
        for j in other.joints.iter() {
            let name = format!("{prefix}{}", j.name);
            if self.joints.iter().any(|x| x.name == name) || name == attach_name {
                return Err(ModelError::DuplicateName { kind: "joint", name });
            }
            let mut j2 = j.clone();
            j2.name = name;
            j2.parent += offset;
            j2.child += offset;
            self.joints.push(j2);
        }
        if self.joints.iter().any(|x| x.name == attach_name) {
            return Err(ModelError::DuplicateName { kind: "joint", name: attach_name });
        }
        self.joints.push(JointDesc {
            name: attach_name,
            kind: JointKind::Fixed,
            parent: at_idx,
            child: other.root + offset,
            origin: pose,
            axis: Vector3::x(),
            lower: 0.0,
            upper: 0.0,
            effort: 0.0,
            velocity: 0.0,
        });
        self.root = check_tree(&self.links, &self.joints)?;
        Ok(self)
    }

    /// Reads `urdf` and attaches it (see [`ModelBuilder::attach`]).
    pub fn attach_urdf_str(
        self,
        urdf: &str,
        at: &str,
        pose: SE3,
        prefix: &str,
    ) -> Result<Self, ModelError> {
        let other = ModelBuilder::from_urdf_str(urdf)?;
        self.attach(other, at, pose, prefix)
    }

    pub fn attach_urdf_file(
        self,
        path: impl AsRef<Path>,
        at: &str,
        pose: SE3,
        prefix: &str,
    ) -> Result<Self, ModelError> {
        let other = ModelBuilder::from_urdf_file(path)?;
        self.attach(other, at, pose, prefix)
    }

    /// Builds the model: fixed joints merged into their parent body (inertia lumped with the
    /// parallel-axis theorem), bodies in depth-first order.
    pub fn build(&self, floating: FloatingBase) -> Result<Model, ModelError> {
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); self.links.len()];
        for (ji, j) in self.joints.iter().enumerate() {
            children[j.parent].push(ji);
        }
        let floating = floating == FloatingBase::Yes;
        let mut t = Tables::with_root(&self.links[self.root], floating);

        // iterative depth-first traversal (no recursion on outside input): entries are
        // (joint, parent body, parent body -> joint's parent link, parent link's frame);
        // children are pushed in reverse so that they are visited in file order
        let mut stack: Vec<(usize, usize, SE3, FrameId)> =
            children[self.root].iter().rev().map(|&ji| (ji, 0, SE3::identity(), 0)).collect();
        while let Some((ji, body, b_m_l, parent_frame)) = stack.pop() {
            let j = &self.joints[ji];
            let child = &self.links[j.child];
            let b_m_c = b_m_l.compose(&j.origin);
            let (child_body, child_placement) = match j.kind {
                JointKind::Fixed => t.merge_fixed(body, b_m_c, child, parent_frame),
                kind => t.add_moving(kind, j, body, b_m_c, child, parent_frame),
            };
            let child_frame = t.frames.len() - 1;
            for &cj in children[j.child].iter().rev() {
                stack.push((cj, child_body, child_placement, child_frame));
            }
        }

        let frame_index = frame_index(&t.frames)?;
        let total_mass = self.links.iter().map(|l| l.inertia.mass).sum();
        tracing::debug!(
            robot = %self.name,
            nq = t.nq,
            nv = t.nv,
            bodies = t.bodies.len(),
            frames = t.frames.len(),
            total_mass,
            "dynamics model built"
        );
        Ok(Model {
            name: self.name.clone(),
            bodies: t.bodies,
            frames: t.frames,
            frame_index,
            floating_base: floating,
            nq: t.nq,
            nv: t.nv,
            joint_names: t.joint_names,
            lower_position_limit: t.lower.into(),
            upper_position_limit: t.upper.into(),
            velocity_limit: t.vel.into(),
            effort_limit: t.eff.into(),
            actuated: t.actuated,
            total_mass,
            gravity: Vector3::from(GRAVITY),
        })
    }
}

/// The model's tables as [`ModelBuilder::build`] fills them, body by body in depth-first order.
struct Tables {
    bodies: Vec<Body>,
    frames: Vec<Frame>,
    joint_names: Vec<String>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    vel: Vec<f64>,
    eff: Vec<f64>,
    actuated: Vec<bool>,
    nq: usize,
    nv: usize,
}

impl Tables {
    /// The root body (on a free joint when `floating`, else fixed to the world) and its frame.
    fn with_root(root: &LinkDesc, floating: bool) -> Self {
        let mut t = Tables {
            bodies: Vec::new(),
            frames: Vec::new(),
            joint_names: Vec::new(),
            lower: Vec::new(),
            upper: Vec::new(),
            vel: Vec::new(),
            eff: Vec::new(),
            actuated: Vec::new(),
            nq: 0,
            nv: 0,
        };
        let root_joint = if floating { JointType::Free } else { JointType::Fixed };
        t.bodies.push(Body {
            name: root.name.clone(),
            joint_name: if floating { "base".into() } else { String::new() },
            parent: None,
            joint: root_joint,
            placement: SE3::identity(),
            inertia: root.inertia,
            idx_q: 0,
            idx_v: 0,
            support: (0..root_joint.nv()).collect(),
        });
        if floating {
            t.nq = 7;
            t.nv = 6;
            t.lower.extend([f64::NEG_INFINITY; 3]);
            t.upper.extend([f64::INFINITY; 3]);
            t.lower.extend([-1.0; 4]);
            t.upper.extend([1.0; 4]);
            t.vel.extend([f64::INFINITY; 6]);
            t.eff.extend([f64::INFINITY; 6]);
            t.actuated.extend([false; 6]);
        }
        t.frames.push(Frame {
            name: root.name.clone(),
            body: 0,
            placement: SE3::identity(),
            kind: FrameKind::Body,
            parent_frame: None,
        });
        t
    }

    /// A fixed joint: the child link's inertia is lumped into `body` and the link becomes a
    /// frame of it at `b_m_c`. Returns the body and placement the link's children hang from.
    fn merge_fixed(
        &mut self,
        body: usize,
        b_m_c: SE3,
        child: &LinkDesc,
        parent_frame: FrameId,
    ) -> (usize, SE3) {
        // lump the child's inertia into the body (Featherstone eq. 2.71: I = sum X* I X)
        let lumped = b_m_c.act_inertia(&child.inertia);
        self.bodies[body].inertia = self.bodies[body].inertia.add(&lumped);
        self.frames.push(Frame {
            name: child.name.clone(),
            body,
            placement: b_m_c,
            kind: FrameKind::FixedLink,
            parent_frame: Some(parent_frame),
        });
        (body, b_m_c)
    }

    /// A moving joint `j` (of `kind`): a new body, child of `body` at `b_m_c`, with one
    /// configuration and one velocity coordinate. Returns the new body and the identity.
    fn add_moving(
        &mut self,
        kind: JointKind,
        j: &JointDesc,
        body: usize,
        b_m_c: SE3,
        child: &LinkDesc,
        parent_frame: FrameId,
    ) -> (usize, SE3) {
        let joint = match kind {
            JointKind::Prismatic => JointType::Prismatic { axis: j.axis },
            _ => JointType::Revolute { axis: j.axis },
        };
        let mut support = self.bodies[body].support.clone();
        support.push(self.nv);
        self.bodies.push(Body {
            name: child.name.clone(),
            joint_name: j.name.clone(),
            parent: Some(body),
            joint,
            placement: b_m_c,
            inertia: child.inertia,
            idx_q: self.nq,
            idx_v: self.nv,
            support,
        });
        self.nq += 1;
        self.nv += 1;
        self.joint_names.push(j.name.clone());
        self.lower.push(j.lower);
        self.upper.push(j.upper);
        self.vel.push(j.velocity);
        self.eff.push(j.effort);
        self.actuated.push(j.effort > 0.0);
        let nb = self.bodies.len() - 1;
        self.frames.push(Frame {
            name: child.name.clone(),
            body: nb,
            placement: SE3::identity(),
            kind: FrameKind::Body,
            parent_frame: Some(parent_frame),
        });
        (nb, SE3::identity())
    }
}

/// Frame ids by name; every frame name once.
fn frame_index(frames: &[Frame]) -> Result<HashMap<String, FrameId>, ModelError> {
    let mut frame_index = HashMap::new();
    for (i, f) in frames.iter().enumerate() {
        if frame_index.insert(f.name.clone(), i).is_some() {
            return Err(ModelError::DuplicateName { kind: "frame", name: f.name.clone() });
        }
    }
    Ok(frame_index)
}

/// Inertia of a URDF link in the link frame.
fn link_inertia(l: &urdf_rs::Link) -> Result<Inertia, ModelError> {
    let inl = &l.inertial;
    let what = || format!("link {:?} inertial", l.name);
    let m = finite(inl.mass.value, what)?;
    if m < 0.0 {
        return Err(ModelError::BadNumber { what: what(), detail: format!("negative mass {m}") });
    }
    let i = &inl.inertia;
    for x in [i.ixx, i.ixy, i.ixz, i.iyy, i.iyz, i.izz] {
        finite(x, what)?;
    }
    if i.ixx < 0.0 || i.iyy < 0.0 || i.izz < 0.0 {
        return Err(ModelError::BadNumber {
            what: what(),
            detail: "negative moment of inertia".into(),
        });
    }
    let origin = pose_to_se3(&inl.origin, &what())?;
    // inertia tensor about the COM, in the inertial frame; rotate into the link frame
    let ic = Matrix3::new(i.ixx, i.ixy, i.ixz, i.ixy, i.iyy, i.iyz, i.ixz, i.iyz, i.izz);
    Ok(Inertia::new(m, origin.trans, origin.rot * ic * origin.rot.transpose()))
}

/// Checks that links and joints form one tree; returns the root link.
fn check_tree(links: &[LinkDesc], joints: &[JointDesc]) -> Result<usize, ModelError> {
    let mut parent_joint: Vec<Vec<usize>> = vec![Vec::new(); links.len()];
    for (ji, j) in joints.iter().enumerate() {
        parent_joint[j.child].push(ji);
    }
    if let Some((li, js)) = parent_joint.iter().enumerate().find(|(_, js)| js.len() > 1) {
        return Err(ModelError::SeveralParentJoints {
            link: links[li].name.clone(),
            joints: js.iter().map(|&j| joints[j].name.clone()).collect(),
        });
    }
    let roots: Vec<usize> = (0..links.len()).filter(|&l| parent_joint[l].is_empty()).collect();
    let root = match roots.len() {
        0 => return Err(ModelError::NoRoot),
        1 => roots[0],
        _ => {
            return Err(ModelError::MultipleRoots {
                roots: roots.iter().map(|&l| links[l].name.clone()).collect(),
            })
        }
    };
    // every link must be reachable from the root; with one parent per link, an unreachable
    // link lies on (or hangs from) a cycle
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); links.len()];
    for j in joints {
        children[j.parent].push(j.child);
    }
    let mut seen = vec![false; links.len()];
    let mut stack = vec![root];
    seen[root] = true;
    while let Some(l) = stack.pop() {
        for &c in &children[l] {
            if !seen[c] {
                seen[c] = true;
                stack.push(c);
            }
        }
    }
    if let Some(l) = seen.iter().position(|s| !s) {
        // walk up the parents from the unreachable link until a link repeats: that one is on the
        // cycle
        let mut visited = vec![false; links.len()];
        let mut cur = l;
        while !visited[cur] {
            visited[cur] = true;
            cur = joints[parent_joint[cur][0]].parent;
        }
        return Err(ModelError::Cycle { link: links[cur].name.clone() });
    }
    Ok(root)
}
