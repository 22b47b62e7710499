//! The team's capacity (`team capacity`): the heaviest object a plan's team holds at its start
//! pose, along its whole motion ([`crate::payload`]) and, for a walk, what its planner accepts.

use std::sync::Arc;

use coordinator::capacity::{Capacity, REACHED_TOL};
use coordinator::PidcConfig;
use robot_model::Robot;

use crate::payload::{
    motion, pidc_config, samples_of, start_hand_loads, static_problem, CheckError,
};
use crate::plan::Plan;

/// The heaviest object of a scenario: at its start pose, along its whole motion, and what its
/// walk's planner accepts.
#[derive(Debug, Clone)]
pub struct ScenarioCapacity {
    pub start: Capacity,
    pub motion: motion::MotionCapacity,
    /// A walk's planner refusing a lighter object than the team problem along the motion
    /// holds (its arm-torque and support checks with the torsos shifted for the steps).
    pub walk: Option<WalkLimit>,
    /// The scenario's payload margin: the plan checks the object's mass and this share more.
    pub margin: f64,
}

/// The heaviest object a walk's planner accepts, within the bisection's tolerance.
#[derive(Debug, Clone)]
pub struct WalkLimit {
    pub mass: f64,
    /// The lightest mass refused, and why.
    pub refused_at: f64,
    pub reason: String,
}

impl ScenarioCapacity {
    /// The team problem's capacity along the whole motion.
    pub fn whole(&self) -> &Capacity {
        &self.motion.capacity
    }

    /// The heaviest object the plan accepts: held along the motion with the payload margin
    /// and, for a walk, accepted by the walk's planner.
    pub fn mass(&self) -> f64 {
        let held = self.whole().mass.min(self.start.mass) / (1.0 + self.margin);
        self.walk.as_ref().map_or(held, |w| w.mass.min(held))
    }
}

/// The walk of `plan` planned again for an object of `mass` kg (its steps are planned with the
/// hands' loads at the start pose): the planner's refusal, if it refuses.
fn walk_refuses(
    plan: &Plan,
    robots: &[Arc<Robot>],
    cfg: &PidcConfig,
    mass: f64,
) -> Result<Option<String>, CheckError> {
    let mut world = plan.scene.world.clone();
    let object = world.object.as_mut().ok_or(CheckError::NoObject)?;
    object.mass = mass;
    let object = *object;
    let loads = start_hand_loads(&world, robots, cfg, None)?;
    Ok(crate::plan::plan_walk(&plan.scenario, &plan.robots, &plan.scene, &object, &loads)
        .err()
        .map(|e| e.to_string()))
}

/// The heaviest object a plan's walk accepts, by bisection below `upper` kg (`None`: it
/// accepts `upper`, or the plan has no walk).
fn walk_limit(
    plan: &Plan,
    robots: &[Arc<Robot>],
    cfg: &PidcConfig,
    upper: f64,
    tolerance: f64,
) -> Result<Option<WalkLimit>, CheckError> {
    if plan.references.walk.is_none() {
        return Ok(None);
    }
    let Some(mut reason) = walk_refuses(plan, robots, cfg, upper)? else { return Ok(None) };
    let (mut lo, mut hi) = (0.0, upper);
    while hi - lo > tolerance {
        let mid = 0.5 * (lo + hi);
        match walk_refuses(plan, robots, cfg, mid)? {
            None => lo = mid,
            Some(r) => (hi, reason) = (mid, r),
        }
    }
    Ok(Some(WalkLimit { mass: lo, refused_at: hi, reason }))
}

/// The heaviest object the plan's team holds at its start pose, within `tolerance` kg.
pub fn start_capacity(plan: &Plan, tolerance: f64) -> Result<Capacity, CheckError> {
    Ok(static_problem(&plan.scene.world, &plan.loaded_robots(), pidc_config(&plan.controller)?)?
        .capacity(tolerance)?)
}

/// The heaviest object the plan's team holds at its start pose and along its whole motion,
/// within `tolerance` kg ([`ScenarioCapacity::whole`] is what the plan's check agrees with).
pub fn capacity(plan: &Plan, tolerance: f64) -> Result<ScenarioCapacity, CheckError> {
    let cfg = pidc_config(&plan.controller)?;
    let (world, robots) = (&plan.scene.world, plan.loaded_robots());
    let start = start_capacity(plan, tolerance)?;
    let motion =
        motion::capacity_along(&samples_of(world, &robots, &plan.references, cfg)?, tolerance)?;
    let margin = plan.scenario.payload_margin;
    let walk = walk_limit(plan, &robots, cfg, motion.capacity.mass / (1.0 + margin), tolerance)?;
    Ok(ScenarioCapacity { start, motion, walk, margin })
}

/// The capacity as `team capacity` prints it.
pub fn summary(plan: &Plan, cap: &ScenarioCapacity, tolerance: f64, seconds: f64) -> String {
    let s = &plan.scenario;
    let mut out = format!(
        "{}: {} robots, object {:?} m at {:?}, friction_margin {:.3}, patch_margin {:.3}, \
         min_hand_force {} N, min_foot_force {} N\n",
        s.name,
        s.robots.len(),
        s.object.size,
        s.object.position,
        s.friction_margin,
        s.patch_margin,
        s.min_hand_force,
        s.min_foot_force
    );
    let whole = cap.whole();
    out += &format!(
        "capacity: {:.3} kg (the heaviest object the plan accepts: held along the motion with \
         {} % more, payload_margin; bisection to {tolerance} kg, {:.0} ms)\n",
        cap.mass(),
        100.0 * cap.margin,
        1e3 * seconds
    );
    out += &format!(
        "  at the start pose: {:.3} kg ({} static problems)\n",
        cap.start.mass, cap.start.solves
    );
    let m = &cap.motion;
    let p = m.object;
    out += &format!(
        "  along the motion: {:.3} kg, {} poses sampled; the smallest margin at t = {:.2} s \
         (object at [{:.3}, {:.3}, {:.3}] m; {} problems)\n",
        m.capacity.mass, m.samples, m.at_s, p.x, p.y, p.z, m.capacity.solves
    );
    if let Some(w) = &cap.walk {
        out += &format!(
            "  the walk's planner: {:.3} kg; at {:.4} kg it refuses: {}\n",
            w.mass, w.refused_at, w.reason
        );
    }
    out += &format!(
        "limits the forces holding {:.3} kg reach at t = {:.2} s (within {REACHED_TOL} N or Nm):\n",
        whole.mass, m.at_s
    );
    for b in &whole.reached {
        out += &format!("  {b}\n");
    }
    out += &format!(
        "binding limits at {:.3} kg (the relaxed problem's excess), largest first:\n",
        whole.infeasible_at
    );
    for b in &whole.binding {
        out += &format!("  {b}\n");
    }
    out
}
