//! Timed external wrenches on the object or on any robot body, applied through MuJoCo's
//! `xfrc_applied` (world frame, `[force; moment]`, force acting at the body's centre of mass).
//! From the scenario (a list) or from the `team/{team}/perturbation` key
//! ([`protocol::PerturbationRequest`]); a request without `start` starts at the next step.

use mujoco_rs::mujoco_c::{mjData, mjModel, mjtObj};
use protocol::{PerturbationRequest, PerturbationTarget};

use crate::world::{name2id, World, WorldError};

/// One wrench on one body over `[start, start + duration)` of simulated time.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Perturbation {
    pub target: PerturbationTarget,
    /// `[f_x, f_y, f_z, m_x, m_y, m_z]`, world frame, at the body's centre of mass.
    pub wrench: [f64; 6],
    pub start: f64,
    pub duration: f64,
}

/// The active and pending perturbations.
#[derive(Debug, Default, Clone)]
pub struct Perturbations {
    list: Vec<(Perturbation, Option<usize>)>,
    /// Bodies that had a wrench last step (cleared before applying the next).
    touched: Vec<usize>,
    pub applied_steps: u64,
}

impl Perturbations {
    /// Add a perturbation; its body is resolved against the world (typed error if unknown).
    pub fn add(&mut self, world: &World, p: Perturbation) -> Result<(), WorldError> {
        if !(p.wrench.iter().all(|x| x.is_finite())
            && p.start.is_finite()
            && p.duration.is_finite()
            && p.duration > 0.0)
        {
            return Err(WorldError::Invalid(
                "perturbation: wrench, start and duration must be finite, duration > 0".into(),
            ));
        }
        let body = resolve(world, &p.target)?;
        self.list.push((p, Some(body)));
        Ok(())
    }

    /// Add a request received on the perturbation key; `now` is the current simulated time.
    pub fn add_request(
        &mut self,
        world: &World,
        req: &PerturbationRequest,
        now: f64,
    ) -> Result<(), WorldError> {
        self.add(
            world,
            Perturbation {
                target: req.target.clone(),
                wrench: req.wrench,
                start: req.start.unwrap_or(now),
                duration: req.duration,
            },
        )
    }

    pub fn len(&self) -> usize {
        self.list.len()
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// Write the wrenches active at time `t` into `xfrc_applied`.
    pub(crate) fn apply(&mut self, _m: &mjModel, d: &mut mjData, _world: &World, t: f64) {
        for &b in &self.touched {
            for k in 0..6 {
                unsafe { *d.xfrc_applied.add(6 * b + k) = 0.0 };
            }
        }
        self.touched.clear();
        let mut any = false;
        for (p, body) in &self.list {
            let Some(b) = *body else { continue };
            if t + 1e-12 >= p.start && t < p.start + p.duration - 1e-12 {
                for k in 0..6 {
                    unsafe { *d.xfrc_applied.add(6 * b + k) += p.wrench[k] };
                }
                self.touched.push(b);
                any = true;
            }
        }
        if any {
            self.applied_steps += 1;
        }
        // Forget finished ones.
        self.list.retain(|(p, _)| t < p.start + p.duration);
    }
}

fn resolve(world: &World, target: &PerturbationTarget) -> Result<usize, WorldError> {
    let raw = world.model.ffi();
    match target {
        PerturbationTarget::Object => world.object.map(|o| o.0).ok_or_else(|| {
            WorldError::Invalid("perturbation on the object, but the world has none".into())
        }),
        PerturbationTarget::RobotBody { robot, body } => {
            if !world.robots.iter().any(|r| &r.id == robot) {
                return Err(WorldError::Invalid(format!("perturbation on unknown robot {robot}")));
            }
            name2id(raw, mjtObj::mjOBJ_BODY, "body", &format!("{robot}/{body}"))
        }
    }
}
