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
    #[error(
        "{path} is a configuration for mode {mode}, not a router \
         (write one with team router-config)"
    )]
    NotARouter { path: String, mode: String },
    #[error(
        "{path}: a router without access control would let every team into every other \
         (write one with team router-config)"
    )]
    NoAccessControl { path: String },
    #[error("{path}: {reason}")]
    NotSecure { path: String, reason: String },
    #[error("the router could not start: {0}")]
    Open(String),
}

/// A site's router, running.
pub struct Router {
    pub session: Session,
    /// The endpoints its configuration listens on.
    pub listen: Vec<String>,
}

/// Open a Zenoh router from the configuration at `path`: router mode, access control and
/// mutual TLS endpoints ([`protocol::access::SECURE_LINK`]) are required, so that a wrong file
/// does not open a site to everyone.
pub async fn open_router(path: &Path) -> Result<Router, SiteError> {
    let shown = path.display().to_string();
    let config = zenoh::Config::from_file(path)
        .map_err(|e| SiteError::Config { path: shown.clone(), reason: e.to_string() })?;
    let mode = config.get_json("mode").unwrap_or_default().trim_matches('"').to_string();
    if mode != "router" {
        return Err(SiteError::NotARouter { path: shown, mode });
    }
    if config.get_json("access_control/enabled").ok().as_deref() != Some("true") {
        return Err(SiteError::NoAccessControl { path: shown });
    }
    let listen: Vec<String> = config
        .get_json("listen/endpoints")
        .ok()
        .and_then(|j| serde_json::from_str(&j).ok())
        .unwrap_or_default();
    protocol::access::check_secure(&listen)
        .map_err(|e| SiteError::NotSecure { path: shown, reason: e.to_string() })?;
    let session = zenoh::open(config).await.map_err(|e| SiteError::Open(e.to_string()))?;
    Ok(Router { session, listen })
}
