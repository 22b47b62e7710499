//! `robot-agent inspect`: load a robot (optionally composed with an arm), evaluate its
//! dynamics at one state and report them as JSON. The binary is a thin wrapper; everything
//! here returns typed errors and never panics on outside input.

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, DVector, Matrix6xX};
use serde_json::{json, Value};
use thiserror::Error;

use robot_model::{
    compute_all_terms, frame_jacobian, frame_jdot_v, Data, DynamicsError, FloatingBase, Model,
    ModelBuilder, ModelError, SE3,
};

/// A second URDF to attach to a frame of the first.
#[derive(Debug, Clone, PartialEq)]
pub struct Attach {
    pub urdf: PathBuf,
    /// Link (frame) of the first robot to attach to.
    pub at: String,
    /// Pose of the attached root in `at`: x, y, z, roll, pitch, yaw (URDF convention).
    pub pose: [f64; 6],
    /// Prefix for the attached robot's joint and link names.
    pub prefix: String,
}

/// Arguments of `inspect`.
#[derive(Debug, Clone, PartialEq)]
pub struct InspectArgs {
    pub urdf: PathBuf,
    pub floating_base: bool,
    pub attach: Option<Attach>,
    /// JSON file `{"q": [...], "v": [...]}`; default: neutral configuration, zero velocity.
    pub state: Option<PathBuf>,
    pub frames: Vec<String>,
}

#[derive(Debug, Error)]
pub enum InspectError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("state: {0}")]
    Dynamics(#[from] DynamicsError),
    #[error("cannot read state file {path}: {detail}")]
    StateFile { path: String, detail: String },
    #[error("malformed state file {path}: {detail}")]
    StateFormat { path: String, detail: String },
    #[error("bad --pose {value:?}: {detail}")]
    Pose { value: String, detail: String },
}

/// Parses `x,y,z,roll,pitch,yaw` (six finite numbers).
pub fn parse_pose(s: &str) -> Result<[f64; 6], InspectError> {
    let bad = |detail: String| InspectError::Pose { value: s.to_string(), detail };
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 6 {
        return Err(bad(format!("expected 6 comma-separated numbers, got {}", parts.len())));
    }
    let mut out = [0.0; 6];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.parse::<f64>().map_err(|e| bad(format!("{p:?}: {e}")))?;
        if !o.is_finite() {
            return Err(bad(format!("{p:?} is not finite")));
        }
    }
    Ok(out)
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StateFile {
    q: Vec<f64>,
    #[serde(default)]
    v: Option<Vec<f64>>,
}

fn read_state(path: &Path, model: &Model) -> Result<(DVector<f64>, DVector<f64>), InspectError> {
    let p = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| InspectError::StateFile { path: p.clone(), detail: e.to_string() })?;
    let s: StateFile = serde_json::from_str(&text)
        .map_err(|e| InspectError::StateFormat { path: p.clone(), detail: e.to_string() })?;
    let v = s.v.unwrap_or_else(|| vec![0.0; model.nv]);
    model.check_state(&s.q, Some(&v))?;
    if model.floating_base {
        let n = s.q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
        if (n - 1.0).abs() > 1e-6 {
            return Err(InspectError::StateFormat {
                path: p,
                detail: format!("base quaternion (q[3..7], w x y z) has norm {n}, expected 1"),
            });
        }
    }
    Ok((DVector::from_vec(s.q), DVector::from_vec(v)))
}

/// Loads the model described by `args` (frames are checked later).
pub fn load_model(args: &InspectArgs) -> Result<Model, InspectError> {
    let fb = if args.floating_base { FloatingBase::Yes } else { FloatingBase::No };
    let mut b = ModelBuilder::from_urdf_file(&args.urdf)?;
    if let Some(a) = &args.attach {
        let p = a.pose;
        b = b.attach_urdf_file(
            &a.urdf,
            &a.at,
            SE3::from_xyz_rpy([p[0], p[1], p[2]], [p[3], p[4], p[5]]),
            &a.prefix,
        )?;
    }
    Ok(b.build(fb)?)
}

fn matrix_rows(m: &DMatrix<f64>) -> Value {
    Value::Array(
        (0..m.nrows()).map(|r| json!(m.row(r).iter().copied().collect::<Vec<f64>>())).collect(),
    )
}

/// Runs `inspect` and returns the report.
pub fn inspect(args: &InspectArgs) -> Result<Value, InspectError> {
    let model = load_model(args)?;
    let frame_ids = args.frames.iter().map(|f| model.frame_id(f)).collect::<Result<Vec<_>, _>>()?;
    let (q, v) = match &args.state {
        Some(p) => read_state(p, &model)?,
        None => (model.neutral(), DVector::zeros(model.nv)),
    };
    let mut data = Data::new(&model);
    compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice())?;
    let mut jac = Matrix6xX::zeros(model.nv);
    let mut frames = Vec::new();
    for (name, &f) in args.frames.iter().zip(&frame_ids) {
        let x = data.o_m_f[f];
        frame_jacobian(&model, &data, f, &mut jac)?;
        let jdv = frame_jdot_v(&model, &data, f)?;
        let jd = DMatrix::from_column_slice(6, model.nv, jac.as_slice());
        let rot = DMatrix::from_column_slice(3, 3, x.rot.as_slice());
        frames.push(json!({
            "name": name,
            "position": x.trans.as_slice(),
            "rotation": matrix_rows(&rot),
            "jacobian": matrix_rows(&jd),
            "jdot_v": jdv.as_slice(),
        }));
    }
    let convention = if model.floating_base {
        "floating base: q = [base position (world, 3); base quaternion (w, x, y, z); joint \
         positions], v = [base linear velocity in the base frame (3); base angular velocity in \
         the base frame (3); joint velocities] (Pinocchio's convention; MuJoCo's free joint \
         differs: its linear velocity is in the world frame)"
    } else {
        "fixed base: q = joint positions, v = joint velocities"
    };
    Ok(json!({
        "robot": model.name,
        "joint_names": model.joint_names,
        "velocity_names": model.velocity_names(),
        "configuration_names": model.configuration_names(),
        "nq": model.nq,
        "nv": model.nv,
        "total_mass": model.total_mass,
        "floating_base": model.floating_base,
        "base_velocity_convention": convention,
        "frame_convention": "at the frame origin, world-aligned axes, rows [linear; angular]; \
            jdot_v is the classical acceleration at zero joint acceleration (includes omega x v)",
        "gravity": model.gravity.as_slice(),
        "q": q.as_slice(),
        "v": v.as_slice(),
        "M": matrix_rows(&data.m),
        "h": data.h.as_slice(),
        "g": data.g.as_slice(),
        "frames": frames,
    }))
}

/// Short human-readable form of a report (when `--json` is not given).
pub fn summary(report: &Value) -> String {
    let mut s = String::new();
    for key in ["robot", "nq", "nv", "total_mass", "base_velocity_convention", "velocity_names"] {
        s.push_str(&format!("{key}: {}\n", report[key]));
    }
    for key in ["h", "g"] {
        s.push_str(&format!("{key}: {}\n", report[key]));
    }
    if let Some(frames) = report["frames"].as_array() {
        for f in frames {
            s.push_str(&format!(
                "frame {}: position {} jdot_v {}\n",
                f["name"], f["position"], f["jdot_v"]
            ));
        }
    }
    s.push_str("(use --json for M, rotations and Jacobians)\n");
    s
}
