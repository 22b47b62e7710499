//! Typed errors of the dynamics module.

use thiserror::Error;

/// Errors while building a [`crate::Model`] (URDF parsing, tree checks, composition).
#[derive(Debug, Error)]
pub enum ModelError {
    #[error("cannot read URDF file {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("malformed URDF: {0}")]
    Urdf(String),
    #[error("URDF has no links")]
    Empty,
    #[error("URDF has no root link (every link is the child of a joint)")]
    NoRoot,
    #[error("URDF has several root links: {roots:?}")]
    MultipleRoots { roots: Vec<String> },
    #[error("URDF kinematic graph has a cycle through link {link:?}")]
    Cycle { link: String },
    #[error("joint {joint:?} refers to unknown {role} link {link:?}")]
    UnknownParent { joint: String, role: &'static str, link: String },
    #[error("duplicate {kind} name {name:?}")]
    DuplicateName { kind: &'static str, name: String },
    #[error("link {link:?} is the child of several joints: {joints:?}")]
    SeveralParentJoints { link: String, joints: Vec<String> },
    #[error("bad number in {what}: {detail}")]
    BadNumber { what: String, detail: String },
    #[error("joint {joint:?} has unsupported type {kind}")]
    UnsupportedJoint { joint: String, kind: String },
    #[error("unknown frame {name:?}")]
    UnknownFrame { name: String },
}

/// Errors of the per-tick algorithms (bad state input).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DynamicsError {
    #[error("{what} has length {got}, expected {expected}")]
    WrongLength { expected: usize, got: usize, what: &'static str },
    #[error("{what} contains a non-finite number at index {index}")]
    NonFinite { what: &'static str, index: usize },
    #[error("base quaternion has zero norm")]
    ZeroQuaternion,
    #[error("frame index {index} out of range ({count} frames)")]
    FrameOutOfRange { index: usize, count: usize },
    #[error("output matrix is {rows}x{cols}, expected {expected_rows}x{expected_cols}")]
    OutputShape { rows: usize, cols: usize, expected_rows: usize, expected_cols: usize },
}
