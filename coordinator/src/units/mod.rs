//! Units of the team problem that any team controller composes (mc_rtc's `MetaTask` and
//! `ConstraintSet` in spirit): the Cartesian impedance tasks ([`impedance`]), the rigid grasp
//! ([`grasp`]), the PIDC projections ([`projection`], by the team's blocks in [`block_projection`]), the tasks' targets ([`targets`]) and
//! when to let go of the object ([`release`]). Each computes into buffers kept
//! between ticks; none knows which controller uses it.

pub mod block_projection;
pub mod grasp;
pub mod impedance;
pub mod projection;
pub mod release;
pub mod targets;
