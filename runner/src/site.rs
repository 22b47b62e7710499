//! `team router`: a site's Zenoh router ([`protocol::site`]), the node that several teams
//! share and that enforces their isolation.

use std::path::Path;

use thiserror::Error;
use zenoh::Session;

/// What can go wrong starting a router.
#[derive(Debug, Error)]
pub enum SiteError {
    #[error("cannot read the router configuration {path}: {reason}")]
    Config { path: String, reason: String },
    #[error("{path} is a configuration for mode {mode}, not a router (write one with team router-config)")]
    NotARouter { path: String, mode: String },
    #[error("{path}: a router without access control would let every team into every other (write one with team router-config)")]
    NoAccessControl { path: String },
    #[error("the router could not start: {0}")]
    Open(String),
}

/// Open a Zenoh router from the configuration at `path`: router mode and access control are
/// required, so that a wrong file does not open a site to everyone.
pub async fn open_router(path: &Path) -> Result<Session, SiteError> {
    let shown = path.display().to_string();
    let config = zenoh::Config::from_file(path).map_err(|e| SiteError::Config { path: shown.clone(), reason: e.to_string() })?;
    let mode = config.get_json("mode").unwrap_or_default().trim_matches('"').to_string();
    if mode != "router" {
        return Err(SiteError::NotARouter { path: shown, mode });
    }
    if config.get_json("access_control/enabled").ok().as_deref() != Some("true") {
        return Err(SiteError::NoAccessControl { path: shown });
    }
    zenoh::open(config).await.map_err(|e| SiteError::Open(e.to_string()))
}

/// The endpoints a configuration listens on, for the operator's first line.
pub fn listen_endpoints(path: &Path) -> String {
    zenoh::Config::from_file(path).ok().and_then(|c| c.get_json("listen/endpoints").ok()).unwrap_or_default()
}
