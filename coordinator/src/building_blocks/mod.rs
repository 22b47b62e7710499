//! Units of the team problem that any team controller composes (mc_rtc's `MetaTask` and
//! `ConstraintSet` in spirit); each computes into buffers kept between ticks and none knows
//! which controller uses it:
//!
//! * the team's contacts: the contact parameters ([`contact_margins`]), the contact list the
//!   QPs constrain ([`contacts`]), the constraint Jacobian ([`contact_jacobian`]) and the
//!   joints' torque limits ([`limits`]);
//! * the tasks: the Cartesian impedance tasks ([`impedance`]), their targets ([`targets`]);
//! * the carried object: the rigid grasp ([`grasp`]), its load on the robots
//!   ([`object_load`]) and when to let go of it ([`release`]);
//! * the PIDC projections ([`projection`], by the team's blocks in [`block_projection`]);
//! * the tick's messages written in place ([`messages`]).

pub mod block_projection;
pub mod contact_jacobian;
pub mod contact_margins;
pub mod contacts;
pub mod grasp;
pub mod impedance;
pub mod limits;
pub mod messages;
pub mod object_load;
pub mod projection;
pub mod release;
pub mod targets;
