//! A scenario's walk as its file gives it (`[walk]`): who walks, the waypoints and their
//! frame, when the first step starts, and the crawl's parameters.

use serde::Deserialize;
use thiserror::Error;

use crate::gait::GaitParams;

/// What is wrong with a walk's specification.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("{0}")]
pub struct WalkSpecError(pub String);

/// The frame of a walk's waypoints.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WalkFrame {
    /// Each walking robot's start torso frame (forward, left, yaw); the object holds its pose
    /// (the paper's S2).
    #[default]
    Robot,
    /// The whole team moves rigidly: world offsets (x, y) and a turn about the object's
    /// start centre; every robot walks and the object's reference moves with the team.
    Team,
}

/// A walk (`docs/walking.md`): waypoints `[dx, dy, yaw_deg]`, each an offset from the start pose
/// (not from the previous waypoint), in `frame`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WalkSpec {
    /// Robots that walk (ids); empty: every robot. In the `team` frame every robot walks.
    #[serde(default)]
    pub robots: Vec<String>,
    #[serde(default)]
    pub frame: WalkFrame,
    pub path: Vec<[f64; 3]>,
    /// Scenario time the first step starts, s.
    #[serde(default)]
    pub start: f64,
    /// The crawl's parameters (stride, lift height, phase durations, margin, ...).
    #[serde(default)]
    pub gait: GaitParams,
}

impl WalkSpec {
    /// A path of finite waypoints, a start at or after 0, walking robots among the team's
    /// (`robots`: every robot's id).
    pub fn check(&self, robots: &[&str]) -> Result<(), WalkSpecError> {
        let bad = |why: String| Err(WalkSpecError(why));
        if self.path.is_empty() {
            return bad("walk.path needs at least one waypoint".into());
        }
        if self.path.iter().flatten().chain([&self.start]).any(|x| !x.is_finite())
            || self.start < 0.0
        {
            return bad("walk.path and walk.start must be finite, start >= 0".into());
        }
        if let Some(r) = self.robots.iter().find(|r| !robots.contains(&r.as_str())) {
            return bad(format!("walk.robots names unknown robot {r:?}"));
        }
        if self.frame == WalkFrame::Team
            && !self.robots.is_empty()
            && self.robots.len() != robots.len()
        {
            return bad(
                "walk.frame = \"team\" moves the whole team: leave walk.robots empty".into()
            );
        }
        Ok(())
    }

    /// Whether robot `id` walks.
    pub fn walks(&self, id: &str) -> bool {
        self.robots.is_empty() || self.robots.iter().any(|r| r == id)
    }
}
