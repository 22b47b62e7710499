//! A site: several teams on one Zenoh router, each isolated from the others by the router's
//! access-control list.
//!
//! A team alone runs in peer mode, its coordinator the hub ([`crate::access`]). A site that
//! hosts several teams (or teams spread over networks) puts a Zenoh router in the middle:
//! every component is a Zenoh *client* of the router, and the router enforces the ACL, since
//! it is the one node at the other end of every client's link. Two teams both have a
//! `coordinator` and maybe an `r1`, so on a site a certificate names its team too:
//! `{identity}.{team}` ([`cert_name`]; identities never contain a dot), e.g. `r1.alpha`,
//! `coordinator.beta`. The router's own certificate is named [`ROUTER`].
//!
//! * [`router_access_control`]: the router's section: for each team, each identity's grants
//!   ([`crate::access::grants`]) on that team's keys, under its site name. Nothing of a team
//!   is granted to another team's identities, so team A can neither publish into team B nor
//!   subscribe to it, and a certificate of one team cannot stand in for another team's.
//! * [`RouterConfig`]: the router's whole configuration: router mode, its TLS endpoints,
//!   mutual TLS with the site's CA, multicast scouting off, that ACL.
//! * [`ClientConfig`]: one component's configuration: client mode, connected to the router
//!   only, mutual TLS with its site certificate, and an ACL of its own that lets the router
//!   carry its team's keys and nothing else (a second check at the client's end of the link).
//!
//! `scripts/make-test-certs.sh --router DIR` makes a site's test CA and the router's
//! certificate; `scripts/make-test-certs.sh --ca DIR --team TEAM TEAMDIR ROBOT...` a team's
//! certificates signed by it. `team router-config`, `team zenoh-config --router` and
//! `team router` write and run these configurations (docs/realtime.md, "A site").

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::access::{
    check_secure, team_section, to_zenoh, write_checked, AccessError, Acl, Identity, TlsFiles,
};
use crate::keys;

/// The common name of a site router's certificate.
pub const ROUTER: &str = "router";

/// The certificate name of `who` of `team` on a site: `{identity}.{team}`.
pub fn cert_name(team: &str, who: &Identity) -> String {
    format!("{}.{team}", who.name())
}

/// One team of a site: its name on the bus and its robots.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SiteTeam {
    pub team: String,
    pub robots: Vec<String>,
}

impl SiteTeam {
    /// `NAME=ROBOT,ROBOT,...` (as `team router-config --team` takes it).
    pub fn parse(text: &str) -> Result<Self, AccessError> {
        let bad = |reason: &str| {
            AccessError::Site(format!("team {text:?}: {reason} (expected NAME=ROBOT,ROBOT,...)"))
        };
        let (team, robots) = text.split_once('=').ok_or_else(|| bad("no '='"))?;
        let robots: Vec<String> =
            robots.split(',').map(str::trim).filter(|r| !r.is_empty()).map(String::from).collect();
        if robots.is_empty() {
            return Err(bad("no robots"));
        }
        crate::validate_id("team", team.trim())?;
        for r in &robots {
            if !matches!(Identity::from_name(r)?, Identity::Agent(_)) {
                return Err(AccessError::ReservedRobotId(r.clone()));
            }
        }
        Ok(SiteTeam { team: team.trim().to_string(), robots })
    }
}

/// The router's `access_control` section for these teams: default deny, every identity of
/// every team by its site name, granted only its own team's keys.
pub fn router_access_control(teams: &[SiteTeam]) -> Result<Value, AccessError> {
    let mut seen = std::collections::BTreeSet::new();
    let mut acl = Acl::default();
    for t in teams {
        if !seen.insert(t.team.as_str()) {
            return Err(AccessError::Site(format!("team {:?} is listed twice", t.team)));
        }
        team_section(&t.team, &t.robots, &|who| cert_name(&t.team, who), &mut acl)?;
    }
    if teams.is_empty() {
        return Err(AccessError::Site("a router needs at least one team".into()));
    }
    Ok(acl.into_json())
}

/// A client's `access_control` section: the router (by its certificate name) may carry the
/// team's keys both ways, every kind of message; nothing else.
pub fn client_access_control(team: &str) -> Result<Value, AccessError> {
    let messages = [
        "put",
        "delete",
        "declare_subscriber",
        "declare_liveliness_subscriber",
        "liveliness_token",
        "liveliness_query",
    ];
    let team_keys = [keys::everything(team)?];
    let mut acl = Acl::default();
    for flow in ["ingress", "egress"] {
        acl.rules.push(json!({
            "id": format!("router/{flow}"),
            "messages": messages,
            "flows": [flow],
            "permission": "allow",
            "key_exprs": team_keys,
        }));
    }
    acl.subjects.push(json!({ "id": ROUTER, "cert_common_names": [ROUTER] }));
    acl.policies.push(
        json!({ "id": ROUTER, "rules": ["router/ingress", "router/egress"], "subjects": [ROUTER] }),
    );
    Ok(acl.into_json())
}

/// A site router's configuration.
#[derive(Debug, Clone)]
pub struct RouterConfig {
    pub teams: Vec<SiteTeam>,
    /// The router's certificate (`DIR/router.pem`) and the site's CA.
    pub tls: TlsFiles,
    /// `quic/HOST:PORT` endpoints the router listens on.
    pub listen: Vec<String>,
}

impl RouterConfig {
    /// The router's files in `dir` ([`TlsFiles::named`] with [`ROUTER`]).
    pub fn in_dir(dir: &Path, teams: Vec<SiteTeam>, listen: Vec<String>) -> Self {
        RouterConfig { teams, tls: TlsFiles::named(dir, ROUTER), listen }
    }

    /// The configuration as JSON (which is JSON5).
    pub fn to_json(&self) -> Result<Value, AccessError> {
        if self.listen.is_empty() {
            return Err(AccessError::Site("a router needs an endpoint to listen on".into()));
        }
        check_secure(&self.listen)?;
        Ok(json!({
            "mode": "router",
            "listen": { "endpoints": self.listen },
            "scouting": { "multicast": { "enabled": false }, "gossip": { "enabled": false } },
            "transport": { "link": { "tls": self.tls.tls_section() } },
            "access_control": router_access_control(&self.teams)?,
        }))
    }

    /// The configuration as a Zenoh configuration (checks that Zenoh accepts it).
    pub fn to_zenoh(&self) -> Result<zenoh::Config, AccessError> {
        to_zenoh(ROUTER, &self.to_json()?)
    }

    /// Check the certificate files and write the configuration to `path`.
    pub fn write(&self, path: &Path) -> Result<(), AccessError> {
        write_checked(path, ROUTER, &self.tls, &self.to_json()?)
    }
}

/// One component's configuration on a site: a client of the router.
#[derive(Debug, Clone)]
pub struct ClientConfig {
    pub team: String,
    pub identity: Identity,
    /// The identity's site certificate (`{identity}.{team}`), in its team's folder.
    pub tls: TlsFiles,
    /// The router's endpoint, `quic/HOST:PORT`.
    pub router: String,
}

impl ClientConfig {
    /// `who`'s files from `dir` (the team's folder: `ca.pem`, `{identity}.pem`, `.key`).
    pub fn in_dir(dir: &Path, team: &str, who: Identity, router: &str) -> Self {
        ClientConfig {
            team: team.to_string(),
            tls: TlsFiles::in_dir(dir, &who),
            identity: who,
            router: router.to_string(),
        }
    }

    /// The configuration as JSON (which is JSON5).
    pub fn to_json(&self) -> Result<Value, AccessError> {
        check_secure(std::slice::from_ref(&self.router))?;
        Ok(json!({
            "mode": "client",
            "connect": { "endpoints": [self.router] },
            "listen": { "endpoints": [] },
            "scouting": { "multicast": { "enabled": false } },
            "transport": { "link": { "tls": self.tls.tls_section() } },
            "access_control": client_access_control(&self.team)?,
        }))
    }

    /// The configuration as a Zenoh configuration (checks that Zenoh accepts it).
    pub fn to_zenoh(&self) -> Result<zenoh::Config, AccessError> {
        to_zenoh(&cert_name(&self.team, &self.identity), &self.to_json()?)
    }

    /// Check the certificate files and write the configuration to `path`.
    pub fn write(&self, path: &Path) -> Result<(), AccessError> {
        write_checked(path, &cert_name(&self.team, &self.identity), &self.tls, &self.to_json()?)
    }
}

/// Write every identity's client configuration of one team into `out`
/// ([`crate::access::file_name`]); returns the files written.
pub fn write_clients(
    certs: &Path,
    team: &SiteTeam,
    router: &str,
    out: &Path,
) -> Result<Vec<PathBuf>, AccessError> {
    std::fs::create_dir_all(out)
        .map_err(|e| AccessError::Write { path: out.to_path_buf(), reason: e.to_string() })?;
    let mut written = Vec::new();
    for who in Identity::all(&team.robots) {
        let path = out.join(crate::access::file_name(&who));
        ClientConfig::in_dir(certs, &team.team, who, router).write(&path)?;
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn site() -> Vec<SiteTeam> {
        vec![SiteTeam::parse("alpha=r1,r2").unwrap(), SiteTeam::parse("beta=r1,r2,r3").unwrap()]
    }

    /// Every rule a subject's policy names, with the keys it allows.
    fn allowed(acl: &Value, subject: &str) -> Vec<(String, String, String)> {
        let rules = acl["rules"].as_array().unwrap();
        let mut out = Vec::new();
        for p in acl["policies"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|p| p["subjects"].as_array().unwrap().iter().any(|s| s == subject))
        {
            for id in p["rules"].as_array().unwrap() {
                let r = rules
                    .iter()
                    .find(|r| &r["id"] == id)
                    .expect("a policy names a rule that exists");
                for m in r["messages"].as_array().unwrap() {
                    for k in r["key_exprs"].as_array().unwrap() {
                        out.push((
                            m.as_str().unwrap().into(),
                            r["flows"][0].as_str().unwrap().into(),
                            k.as_str().unwrap().into(),
                        ));
                    }
                }
            }
        }
        out
    }

    #[test]
    fn a_team_is_granted_only_its_own_keys() {
        let acl = router_access_control(&site()).unwrap();
        for (team, robots) in [("alpha", vec!["r1", "r2"]), ("beta", vec!["r1", "r2", "r3"])] {
            let mut names: Vec<String> = ["coordinator", "sim-bridge", "runner", "tool"]
                .iter()
                .map(|n| format!("{n}.{team}"))
                .collect();
            names.extend(robots.iter().map(|r| format!("{r}.{team}")));
            for name in names {
                let grants = allowed(&acl, &name);
                assert!(!grants.is_empty(), "{name} is granted something");
                let prefix = format!("team/{team}/");
                assert!(
                    grants.iter().all(|(_, _, k)| k.starts_with(&prefix)),
                    "{name}: {grants:?}"
                );
            }
        }
        // A team-less name (a team's own peer certificate) is granted nothing on the router.
        assert!(allowed(&acl, "r1").is_empty() && allowed(&acl, "coordinator").is_empty());
        assert_eq!(acl["default_permission"], "deny");
    }

    #[test]
    fn bad_sites_are_refused() {
        assert!(SiteTeam::parse("alpha").is_err());
        assert!(SiteTeam::parse("alpha=").is_err());
        assert!(SiteTeam::parse("al.pha=r1").is_err());
        assert!(
            SiteTeam::parse("alpha=r1,tool").is_err(),
            "a robot may not take another identity's name"
        );
        let twice = vec![SiteTeam::parse("a=r1").unwrap(), SiteTeam::parse("a=r2").unwrap()];
        assert!(matches!(router_access_control(&twice), Err(AccessError::Site(_))));
        assert!(router_access_control(&[]).is_err());
        assert!(RouterConfig::in_dir(Path::new("/c"), site(), vec![]).to_json().is_err());
    }

    #[test]
    fn zenoh_accepts_router_and_client_configurations() {
        let router =
            RouterConfig::in_dir(Path::new("/site"), site(), vec!["quic/0.0.0.0:7447".into()])
                .to_zenoh()
                .unwrap();
        assert_eq!(router.get_json("mode").unwrap(), "\"router\"");
        assert!(router
            .get_json("transport/link/tls/listen_certificate")
            .unwrap()
            .contains("/site/router.pem"));
        let client = ClientConfig::in_dir(
            Path::new("/alpha"),
            "alpha",
            Identity::Agent("r1".into()),
            "quic/10.0.0.1:7447",
        )
        .to_zenoh()
        .unwrap();
        assert_eq!(client.get_json("mode").unwrap(), "\"client\"");
        assert!(client.get_json("connect/endpoints").unwrap().contains("quic/10.0.0.1:7447"));
        assert!(client.get_json("access_control/subjects").unwrap().contains("\"router\""));
        assert_eq!(cert_name("alpha", &Identity::SimBridge), "sim-bridge.alpha");
    }
}
