//! Cross-crate and multi-process tests of the team live in `tests/`; this library holds what
//! they share that belongs to no product crate.
//!
//! * [`standing_controller`]: a test-side standing controller (PD + gravity compensation on the
//!   robot's
//!   own model) that stands in for the agents or the coordinator in the plant tests.

pub mod standing_controller;
