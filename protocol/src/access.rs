//! Access control: Zenoh configurations with mutual TLS and an access-control list (ACL) that
//! says, per identity, which keys it may publish and subscribe to.
//!
//! An identity is the common name (CN) of the certificate a component presents
//! ([`Identity`]): `coordinator`, each robot's id (its agent), `sim-bridge`, `runner` (the
//! scenario driver: references, contact sets, perturbations, evaluation) and `tool` (read-only:
//! status and diagnostics). [`grants`] lists, from [`crate::keys`], what each may do:
//!
//! - `coordinator`: publishes (puts) `robot/*/command`, `coordinator/{status,diagnostics}`;
//!   subscribes to `robot/*/{dynamics,description}`, `references`; liveliness: declares
//!   `coordinator/alive`, watches `member/*`.
//! - robot `rN`: publishes `robot/rN/{dynamics,torque,status,description}`; subscribes to
//!   `robot/rN/{state,command,contacts}`; liveliness: declares `member/rN`, watches
//!   `coordinator/alive`.
//! - `sim-bridge`: publishes `robot/*/state`, `ground-truth`; subscribes to `robot/*/torque`,
//!   `perturbation`, `coordinator/status`; liveliness: watches `member/*`, `coordinator/alive`.
//! - `runner`: publishes `references`, `robot/*/contacts`, `perturbation`; subscribes to every
//!   robot key, `coordinator/{status,diagnostics}`, `ground-truth`; liveliness: watches
//!   `member/*`, `coordinator/alive`.
//! - `tool`: publishes nothing; subscribes to `robot/*/status`,
//!   `coordinator/{status,diagnostics}`; liveliness: none.
//!
//! (keys under `team/{team}/`). [`access_control`] turns the grants into Zenoh's
//! `access_control` section, default deny. Zenoh enforces it on every node, per link, against
//! the certificate name of the node at the other end: *ingress* rules say what a remote may
//! send us (its puts, its liveliness tokens) and which subscriptions it may declare to us (so
//! that we never route to it what it may not read); *egress* rules say what we may send it
//! (puts and tokens only on keys it may read). Declarations that we send out (our own
//! subscriptions) are allowed towards every team identity. Every component runs the same
//! section, so a message is checked at both ends of each link: a component that runs without
//! it (or with a forged configuration) still cannot get anything past the others.
//!
//! Peers in peer mode do not route for each other, so the remote at the end of a link is the
//! origin of what it sends. A Zenoh router in between would be the remote of every message
//! (its certificate name, not the origin's): a router enforces the ACL itself, by site names
//! that carry the team ([`crate::site`]).
//!
//! [`SecureConfig`] writes one component's whole Zenoh configuration: peer mode, multicast
//! scouting off, QUIC endpoints ([`SECURE_LINK`]), the certificate files ([`TlsFiles`]: CA,
//! certificate, key; `enable_mtls`, so that a node without a certificate from the CA cannot open
//! a link) and the ACL. `scripts/make-test-certs.sh` makes test certificates with these names.
//! Several teams on one network go through a router instead ([`crate::site`]).

use std::path::{Path, PathBuf};

use serde_json::{json, Value};
use thiserror::Error;

use crate::keys::{self, RobotTopic};
use crate::ProtocolError;

/// Errors building an access-controlled configuration.
#[derive(Debug, Error)]
pub enum AccessError {
    #[error(transparent)]
    Key(#[from] ProtocolError),
    #[error(
        "robot id {0:?} is the name of another identity (coordinator, sim-bridge, runner, tool)"
    )]
    ReservedRobotId(String),
    #[error(
        "{what} {path} is missing (make test certificates with scripts/make-test-certs.sh \
         DIR ROBOT..., or --router DIR for a site's router)"
    )]
    MissingFile { what: &'static str, path: PathBuf },
    #[error("cannot write {path}: {reason}")]
    Write { path: PathBuf, reason: String },
    #[error("site: {0}")]
    Site(String),
    #[error(
        "endpoint {0:?} is not a secure link: mutual TLS runs on QUIC endpoints, \
         quic/HOST:PORT (Zenoh's tls/ link reads and writes one TLS session from two tasks at \
         once, which can corrupt it under load)"
    )]
    NotSecure(String),
    #[error("the configuration for {identity} is not a valid Zenoh configuration: {reason}")]
    Invalid { identity: String, reason: String },
}

/// Names that robots may not take: they are the other identities' certificate names.
pub const RESERVED: [&str; 4] = ["coordinator", "sim-bridge", "runner", "tool"];

/// Who a component is: the common name of its certificate.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Identity {
    Coordinator,
    /// A robot's agent, by robot id.
    Agent(String),
    SimBridge,
    /// The scenario driver (`team run`): references, contact sets, perturbations, evaluation.
    Runner,
    /// A read-only tool: status and diagnostics.
    Tool,
}

impl Identity {
    /// The identity a certificate common name stands for (any other name is a robot's).
    pub fn from_name(name: &str) -> Result<Self, AccessError> {
        Ok(match name {
            "coordinator" => Identity::Coordinator,
            "sim-bridge" => Identity::SimBridge,
            "runner" => Identity::Runner,
            "tool" => Identity::Tool,
            robot => {
                crate::validate_id("robot", robot)?;
                Identity::Agent(robot.to_string())
            }
        })
    }

    /// The certificate common name.
    pub fn name(&self) -> &str {
        match self {
            Identity::Coordinator => "coordinator",
            Identity::Agent(r) => r,
            Identity::SimBridge => "sim-bridge",
            Identity::Runner => "runner",
            Identity::Tool => "tool",
        }
    }

    /// Every identity of a team with these robots.
    pub fn all(robots: &[String]) -> Vec<Identity> {
        let mut out =
            vec![Identity::Coordinator, Identity::SimBridge, Identity::Runner, Identity::Tool];
        out.extend(robots.iter().cloned().map(Identity::Agent));
        out
    }
}

/// What one identity may do, as key expressions (wildcards allowed).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Grants {
    /// Keys it may publish (put and delete).
    pub puts: Vec<String>,
    /// Keys it may subscribe to (declare a subscriber, receive puts).
    pub gets: Vec<String>,
    /// Liveliness tokens it may declare.
    pub tokens: Vec<String>,
    /// Liveliness tokens it may watch.
    pub watches: Vec<String>,
}

/// What `who` may do in `team`.
pub fn grants(team: &str, who: &Identity) -> Result<Grants, AccessError> {
    use RobotTopic as T;
    let all = |t| keys::all_robots(team, t);
    let members = keys::all_members(team)?;
    let alive = keys::coordinator_alive(team)?;
    Ok(match who {
        Identity::Coordinator => Grants {
            puts: vec![all(T::Command)?, keys::coordinator_status(team)?, keys::diagnostics(team)?],
            gets: vec![all(T::Dynamics)?, all(T::Description)?, keys::references(team)?],
            tokens: vec![alive],
            watches: vec![members],
        },
        Identity::Agent(robot) => {
            if RESERVED.contains(&robot.as_str()) {
                return Err(AccessError::ReservedRobotId(robot.clone()));
            }
            let own = |t| keys::robot(team, robot, t);
            Grants {
                puts: vec![
                    own(T::Dynamics)?,
                    own(T::Torque)?,
                    own(T::Status)?,
                    own(T::Description)?,
                ],
                gets: vec![own(T::State)?, own(T::Command)?, own(T::Contacts)?],
                tokens: vec![keys::member(team, robot)?],
                watches: vec![alive],
            }
        }
        Identity::SimBridge => Grants {
            puts: vec![all(T::State)?, keys::ground_truth(team)?],
            gets: vec![all(T::Torque)?, keys::perturbation(team)?, keys::coordinator_status(team)?],
            tokens: Vec::new(),
            watches: vec![members, alive],
        },
        Identity::Runner => Grants {
            puts: vec![keys::references(team)?, all(T::Contacts)?, keys::perturbation(team)?],
            gets: runner_gets(team)?,
            tokens: Vec::new(),
            watches: vec![members, alive],
        },
        Identity::Tool => Grants {
            puts: Vec::new(),
            gets: vec![all(T::Status)?, keys::coordinator_status(team)?, keys::diagnostics(team)?],
            tokens: Vec::new(),
            watches: Vec::new(),
        },
    })
}

/// The runner evaluates and records the run: it reads every robot key and the coordinator's.
fn runner_gets(team: &str) -> Result<Vec<String>, AccessError> {
    use RobotTopic as T;
    let mut gets = Vec::new();
    for t in [T::State, T::Dynamics, T::Command, T::Torque, T::Status, T::Description, T::Contacts]
    {
        gets.push(keys::all_robots(team, t)?);
    }
    gets.extend([
        keys::coordinator_status(team)?,
        keys::diagnostics(team)?,
        keys::ground_truth(team)?,
    ]);
    Ok(gets)
}

/// One ACL rule: messages, flows and keys, allowed.
fn rule(id: String, messages: &[&str], flow: &str, keys: &[String]) -> Value {
    json!({
        "id": id,
        "messages": messages,
        "flows": [flow],
        "permission": "allow",
        "key_exprs": keys,
    })
}

/// The rules of one identity of `team`, whose certificate is named `cert`, as seen by the node
/// at the other end of its links.
fn identity_rules(team: &str, who: &Identity, cert: &str) -> Result<Vec<Value>, AccessError> {
    let g = grants(team, who)?;
    let mut rules = Vec::new();
    let mut add = |suffix: &str, messages: &[&str], flow: &str, keys: &[String]| {
        if !keys.is_empty() {
            rules.push(rule(format!("{cert}/{suffix}"), messages, flow, keys));
        }
    };
    add("puts", &["put", "delete"], "ingress", &g.puts);
    add("receives", &["put", "delete"], "egress", &g.gets);
    add("subscribes", &["declare_subscriber"], "ingress", &g.gets);
    add("tokens", &["liveliness_token"], "ingress", &g.tokens);
    add("sees-tokens", &["liveliness_token"], "egress", &g.watches);
    add("watches", &["declare_liveliness_subscriber", "liveliness_query"], "ingress", &g.watches);
    Ok(rules)
}

/// The rules, subjects and policies of one team whose identities' certificates are named by
/// `cert` (the identity's name on a team's own links, `{name}.{team}` on a site's router).
/// Our own declarations (subscribers, liveliness subscribers) go out to every member: a
/// declaration carries no data, and the remote checks it against its own rules.
pub(crate) fn team_section(
    team: &str,
    robots: &[String],
    cert: &dyn Fn(&Identity) -> String,
    acl: &mut Acl,
) -> Result<(), AccessError> {
    let identities = Identity::all(robots);
    let mut names = Vec::new();
    for who in &identities {
        let name = cert(who);
        let own = identity_rules(team, who, &name)?;
        let ids: Vec<Value> = own.iter().map(|r| r["id"].clone()).collect();
        acl.rules.extend(own);
        acl.subjects.push(json!({ "id": name, "cert_common_names": [name] }));
        if !ids.is_empty() {
            acl.policies.push(json!({ "id": name, "rules": ids, "subjects": [name] }));
        }
        names.push(name);
    }
    let id = format!("{team}/declarations");
    acl.rules.push(rule(
        id.clone(),
        &["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
        "egress",
        &[keys::everything(team)?],
    ));
    acl.policies.push(json!({ "id": id, "rules": [id], "subjects": names }));
    Ok(())
}

/// Zenoh's `access_control` section being built: rules, subjects and policies, default deny.
#[derive(Debug, Default)]
pub(crate) struct Acl {
    pub rules: Vec<Value>,
    pub subjects: Vec<Value>,
    pub policies: Vec<Value>,
}

impl Acl {
    /// The finished section, as Zenoh reads it.
    pub fn into_json(self) -> Value {
        json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": self.rules,
            "subjects": self.subjects,
            "policies": self.policies,
        })
    }
}

/// Zenoh's `access_control` section for a team with these robots: default deny, one subject
/// per identity (by certificate common name), each identity's grants as rules.
pub fn access_control(team: &str, robots: &[String]) -> Result<Value, AccessError> {
    let mut acl = Acl::default();
    team_section(team, robots, &|who| who.name().to_string(), &mut acl)?;
    Ok(acl.into_json())
}

/// The Zenoh link that carries mutual TLS: QUIC (TLS 1.3 inside, the same certificates and
/// `transport/link/tls` settings, and the certificate's name for the ACL). Zenoh's `tls/` link
/// (1.10) shares one TLS session between its reading and its writing task without a lock,
/// which is unsound and was seen to corrupt a link under a router's load
/// (<https://github.com/eclipse-zenoh/zenoh/issues/2557>); QUIC keeps the two directions apart.
pub const SECURE_LINK: &str = "quic";

/// A secure endpoint, `quic/HOST:PORT`.
pub fn secure_endpoint(host: impl std::fmt::Display, port: u16) -> String {
    format!("{SECURE_LINK}/{host}:{port}")
}

/// An error naming the first endpoint that is not a [`SECURE_LINK`] endpoint.
pub fn check_secure(endpoints: &[String]) -> Result<(), AccessError> {
    let scheme = format!("{SECURE_LINK}/");
    match endpoints.iter().find(|e| !e.starts_with(&scheme)) {
        Some(e) => Err(AccessError::NotSecure(e.clone())),
        None => Ok(()),
    }
}

/// The CA, certificate and key of one identity.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    pub root_ca: PathBuf,
    pub certificate: PathBuf,
    pub private_key: PathBuf,
}

impl TlsFiles {
    /// The files `scripts/make-test-certs.sh DIR` writes for `who`: `DIR/ca.pem`,
    /// `DIR/{name}.pem`, `DIR/{name}.key`.
    pub fn in_dir(dir: &Path, who: &Identity) -> Self {
        Self::named(dir, who.name())
    }

    /// `DIR/ca.pem`, `DIR/{name}.pem`, `DIR/{name}.key`.
    pub fn named(dir: &Path, name: &str) -> Self {
        TlsFiles {
            root_ca: dir.join("ca.pem"),
            certificate: dir.join(format!("{name}.pem")),
            private_key: dir.join(format!("{name}.key")),
        }
    }

    /// An error naming the first file that is missing.
    pub fn check(&self) -> Result<(), AccessError> {
        for (what, path) in [
            ("CA certificate", &self.root_ca),
            ("certificate", &self.certificate),
            ("private key", &self.private_key),
        ] {
            if !path.is_file() {
                return Err(AccessError::MissingFile { what, path: path.clone() });
            }
        }
        Ok(())
    }

    /// Zenoh's `transport/link/tls` section: the same certificate for both ends of a link,
    /// mutual TLS, the peer's name checked against its certificate.
    pub fn tls_section(&self) -> Value {
        let s = |p: &PathBuf| p.display().to_string();
        json!({
            "root_ca_certificate": s(&self.root_ca),
            "listen_certificate": s(&self.certificate),
            "listen_private_key": s(&self.private_key),
            "connect_certificate": s(&self.certificate),
            "connect_private_key": s(&self.private_key),
            "enable_mtls": true,
            "verify_name_on_connect": true,
        })
    }
}

/// One component's Zenoh configuration with mutual TLS and the team's ACL.
#[derive(Debug, Clone)]
pub struct SecureConfig {
    pub team: String,
    pub robots: Vec<String>,
    pub identity: Identity,
    pub tls: TlsFiles,
    /// `quic/HOST:PORT` endpoints (flags given to the binary override them).
    pub listen: Vec<String>,
    pub connect: Vec<String>,
}

impl SecureConfig {
    /// The configuration with the identity's files from `dir` (see [`TlsFiles::in_dir`]),
    /// listening on a random loopback port and connecting nowhere.
    pub fn in_dir(dir: &Path, team: &str, robots: &[String], identity: Identity) -> Self {
        let tls = TlsFiles::in_dir(dir, &identity);
        SecureConfig {
            team: team.to_string(),
            robots: robots.to_vec(),
            identity,
            tls,
            listen: vec![secure_endpoint("127.0.0.1", 0)],
            connect: Vec::new(),
        }
    }

    /// The configuration as JSON (which is JSON5).
    pub fn to_json(&self) -> Result<Value, AccessError> {
        check_secure(&self.listen)?;
        check_secure(&self.connect)?;
        Ok(json!({
            "mode": "peer",
            "listen": { "endpoints": self.listen },
            "connect": { "endpoints": self.connect },
            "scouting": { "multicast": { "enabled": false } },
            "transport": { "link": { "tls": self.tls.tls_section() } },
            "access_control": access_control(&self.team, &self.robots)?,
        }))
    }

    /// The configuration as a Zenoh configuration (checks that Zenoh accepts it).
    pub fn to_zenoh(&self) -> Result<zenoh::Config, AccessError> {
        to_zenoh(self.identity.name(), &self.to_json()?)
    }

    /// Check the certificate files and write the configuration to `path` (pretty JSON, which
    /// `--zenoh-config` reads as JSON5).
    pub fn write(&self, path: &Path) -> Result<(), AccessError> {
        write_checked(path, self.identity.name(), &self.tls, &self.to_json()?)
    }
}

/// `config` as a Zenoh configuration: an error naming `who` when Zenoh refuses it.
pub(crate) fn to_zenoh(who: &str, config: &Value) -> Result<zenoh::Config, AccessError> {
    let invalid = |reason: String| AccessError::Invalid { identity: who.to_string(), reason };
    let text = serde_json::to_string(config).map_err(|e| invalid(e.to_string()))?;
    zenoh::Config::from_json5(&text).map_err(|e| invalid(e.to_string()))
}

/// Check `who`'s certificate files and that Zenoh accepts `config`, then write it to `path`
/// (pretty JSON, which `--zenoh-config` reads as JSON5).
pub(crate) fn write_checked(
    path: &Path,
    who: &str,
    tls: &TlsFiles,
    config: &Value,
) -> Result<(), AccessError> {
    tls.check()?;
    to_zenoh(who, config)?;
    let failed = |e: String| AccessError::Write { path: path.to_path_buf(), reason: e };
    let text = serde_json::to_string_pretty(config).map_err(|e| failed(e.to_string()))?;
    std::fs::write(path, text + "\n").map_err(|e| failed(e.to_string()))
}

/// The configurations of every identity of a team, the certificates named from `certs` as
/// given (a relative path stays relative: Zenoh resolves it from the component's working
/// directory). The coordinator listens on `hub`; the others listen on a random loopback TLS
/// port and connect to `hub`.
pub fn team_configs(certs: &Path, team: &str, robots: &[String], hub: &str) -> Vec<SecureConfig> {
    let mut out = Vec::new();
    for who in Identity::all(robots) {
        let mut cfg = SecureConfig::in_dir(certs, team, robots, who);
        if cfg.identity == Identity::Coordinator {
            cfg.listen = vec![hub.to_string()];
        } else {
            cfg.connect = vec![hub.to_string()];
        }
        out.push(cfg);
    }
    out
}

/// The file name of an identity's configuration: `zenoh-{identity}.json5`.
pub fn file_name(who: &Identity) -> String {
    format!("zenoh-{}.json5", who.name())
}

/// Write [`team_configs`] into `out` ([`file_name`]); returns the files written.
pub fn write_team(
    certs: &Path,
    team: &str,
    robots: &[String],
    hub: &str,
    out: &Path,
) -> Result<Vec<PathBuf>, AccessError> {
    std::fs::create_dir_all(out)
        .map_err(|e| AccessError::Write { path: out.to_path_buf(), reason: e.to_string() })?;
    let mut written = Vec::new();
    for cfg in team_configs(certs, team, robots, hub) {
        let path = out.join(file_name(&cfg.identity));
        cfg.write(&path)?;
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robots() -> Vec<String> {
        vec!["r1".into(), "r2".into()]
    }

    #[test]
    fn agents_publish_only_their_own_keys() {
        let g = grants("t", &Identity::Agent("r2".into())).unwrap();
        assert!(g.puts.iter().all(|k| k.starts_with("team/t/robot/r2/")), "{:?}", g.puts);
        assert!(!g.puts.iter().any(|k| k.ends_with("/state") || k.ends_with("/command")));
        assert_eq!(g.tokens, vec!["team/t/member/r2".to_string()]);
        assert!(g.gets.contains(&"team/t/robot/r2/command".to_string()));
        assert!(g.gets.iter().all(|k| k.starts_with("team/t/robot/r2/")));
    }

    #[test]
    fn only_the_coordinator_publishes_commands() {
        for who in Identity::all(&robots()) {
            let g = grants("t", &who).unwrap();
            let commands = g.puts.iter().any(|k| k.ends_with("/command"));
            assert_eq!(commands, who == Identity::Coordinator, "{who:?}: {:?}", g.puts);
        }
        let tool = grants("t", &Identity::Tool).unwrap();
        assert!(tool.puts.is_empty() && tool.tokens.is_empty());
    }

    #[test]
    fn reserved_and_bad_names_are_refused() {
        assert!(matches!(
            grants("t", &Identity::Agent("tool".into())),
            Err(AccessError::ReservedRobotId(_))
        ));
        assert!(access_control("t", &["coordinator".to_string()]).is_err());
        assert!(Identity::from_name("a/b").is_err());
        assert_eq!(Identity::from_name("sim-bridge").unwrap(), Identity::SimBridge);
        assert_eq!(Identity::from_name("r7").unwrap(), Identity::Agent("r7".into()));
        assert!(access_control("bad team", &robots()).is_err());
    }

    #[test]
    fn zenoh_accepts_the_configuration() {
        let cfg =
            SecureConfig::in_dir(Path::new("/certs"), "t", &robots(), Identity::Agent("r1".into()));
        let z = cfg.to_zenoh().unwrap();
        assert_eq!(z.get_json("access_control/default_permission").unwrap(), "\"deny\"");
        assert_eq!(z.get_json("transport/link/tls/enable_mtls").unwrap(), "true");
        assert!(z
            .get_json("transport/link/tls/connect_certificate")
            .unwrap()
            .contains("/certs/r1.pem"));
        let missing = cfg.write(Path::new("/nonexistent/zenoh.json5"));
        assert!(matches!(missing, Err(AccessError::MissingFile { .. })), "{missing:?}");
    }

    #[test]
    fn only_quic_endpoints_carry_mutual_tls() {
        let mut cfg =
            SecureConfig::in_dir(Path::new("/certs"), "t", &robots(), Identity::Coordinator);
        assert!(cfg.listen.iter().all(|e| e.starts_with("quic/127.0.0.1:")), "{:?}", cfg.listen);
        for bad in ["tls/127.0.0.1:7447", "tcp/127.0.0.1:7447", "quic127.0.0.1:7447"] {
            cfg.connect = vec![bad.to_string()];
            let refused = cfg.to_json();
            assert!(
                matches!(&refused, Err(AccessError::NotSecure(e)) if e == bad),
                "{bad}: {refused:?}"
            );
        }
        cfg.connect = vec![secure_endpoint("10.0.0.2", 7447)];
        assert_eq!(cfg.to_json().unwrap()["connect"]["endpoints"][0], "quic/10.0.0.2:7447");
    }
}
