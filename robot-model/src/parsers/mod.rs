//! Parsers only build a [`crate::Model`] (Pinocchio's `parsers/`): URDF today.

pub mod urdf;

pub use urdf::ModelBuilder;
