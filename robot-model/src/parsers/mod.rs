//! Parsers only build a [`crate::Model`] (Pinocchio's `parsers/`): URDF today, read after
//! [`urdf_filter::dynamics_only`] has taken out what the dynamics never read.

pub mod urdf;
pub mod urdf_filter;

pub use urdf::ModelBuilder;
