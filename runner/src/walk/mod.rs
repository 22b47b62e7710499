//! A walk in a run: the planner plans it (`planner::walk`), the driver sends its references
//! and contact sets, and [`evaluate`] measures it from the ground truth: steps taken, stance
//! feet that slid, final torso poses.

pub mod evaluate;
