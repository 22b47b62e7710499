//! Helpers shared by the integration tests (each test file includes this module).

#![allow(dead_code)]

pub mod certs;
pub mod hosts;
pub mod machine;
pub mod push;
pub mod scenario;
pub mod skip;
pub mod team;
pub mod tls;
