//! robot-agent: a robot's model (URDF), its dynamics terms, and the agent around them.

pub mod dynamics;
pub mod inspect;
