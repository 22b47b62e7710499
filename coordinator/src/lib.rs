//! # coordinator
//!
//! Solves the team problem every tick (`docs/architecture.md`): it knows who is in the team,
//! gathers every member's dynamics terms of a tick, runs the team controller and publishes
//! each robot its slice of torques ([`service`]).
//!
//! Where each concept lives:
//!
//! * [`controller`]: the interface, [`TeamController`] (what the service drives), and
//!   [`ControllerError`]; it imports no controller.
//! * [`spec`]: [`ControllerSpec`], the choice of controller as data (`kind = "pidc"`,
//!   `"joint-damping"` or `"mqp"` plus its parameters), parsed, checked and built.
//! * [`pidc`]: [`Pidc`], the paper's §III controller (projected inverse dynamics with the
//!   contact-force QP), its [`PidcConfig`], its [`pidc::TickReport`] and its stages
//!   ([`pidc::stages`]).
//! * [`mqp`]: [`Mqp`], the paper's baseline (the multi-robot QP of Bouyarmane et al. 2019,
//!   solved by Clarabel through [`qp::clarabel`]), its [`MqpConfig`] and [`mqp::MqpReport`].
//! * [`joint_damping`]: [`JointDamping`], the smoke run's stand-in.
//! * [`team`]: the team of a tick ([`team::Team`]: block-diagonal `M`, stacked `h`, `v`, `S`,
//!   contact and task frames), membership ([`team::membership`]) and the gathering of a tick's
//!   terms ([`team::assembly`]).
//! * [`building_blocks`]: pieces both controllers and the capacity check compose: the contact
//!   parameters ([`building_blocks::contact_margins::ContactMargins`]), the contact list and
//!   Jacobian, the torque limits, the object's load, impedance tasks and their
//!   targets, the rigid grasp, the
//!   release, the PIDC projections and the tick's messages.
//! * [`qp`]: the contact-force QP (constraint rows, problem, settings with the [`qp::QpPath`]
//!   chain, solvers, the one Clarabel call).
//! * [`linalg`]: pseudo-inverses, inverses and products into preallocated buffers.
//! * [`capacity`]: the static team problem at a pose at rest: whether contact forces within
//!   the controller's limits hold the object, the binding limits when not, the payload capacity.
//! * [`service`], [`diagnostics`]: the Zenoh loop and the diagnostics history.

pub mod building_blocks;
pub mod capacity;
pub mod controller;
pub mod controller_shell;
pub mod diagnostics;
pub mod joint_damping;
pub mod linalg;
pub mod mqp;
pub mod pidc;
pub mod qp;
pub mod service;
pub mod spec;
pub mod team;

pub use controller::{ControllerError, TeamController};
pub use controller_shell::{ControlLaw, Shell, ShellConfig, ShellState};
pub use joint_damping::JointDamping;
pub use mqp::{Mqp, MqpConfig};
pub use pidc::{Pidc, PidcConfig};
pub use spec::ControllerSpec;
