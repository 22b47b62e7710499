//! Zenoh sessions over mutual TLS with the team's access-control list, for the tests that run
//! components under their certificates' identities (`protocol::access`).

use std::path::Path;
use std::time::Duration;

use launch::processes::free_port;
use protocol::access::{Identity, SecureConfig};
use protocol::transport::{self, Role, ZenohArgs};
use zenoh::Session;

/// Write `who`'s configuration into `dir` and return the arguments that use it. `acl: false`
/// drops the access-control section (what a component that ignores the rules would run).
pub fn config(
    dir: &Path,
    team: &str,
    robots: &[String],
    who: Identity,
    listen: &str,
    connect: Option<&str>,
    acl: bool,
) -> ZenohArgs {
    let name = who.name().to_string();
    let mut cfg = SecureConfig::in_dir(dir, team, robots, who);
    cfg.listen = vec![listen.to_string()];
    cfg.connect = connect.map(|c| vec![c.to_string()]).unwrap_or_default();
    let path = dir.join(format!("{name}{}.json5", if acl { "" } else { "-no-acl" }));
    if acl {
        cfg.write(&path).expect("configuration written");
    } else {
        let mut json = cfg.to_json().unwrap();
        json.as_object_mut().unwrap().remove("access_control");
        std::fs::write(&path, json.to_string()).unwrap();
    }
    ZenohArgs { config: Some(path), ..Default::default() }
}

pub async fn open(args: &ZenohArgs) -> Session {
    tokio::time::timeout(Duration::from_secs(10), transport::open(args, Role::Member))
        .await
        .expect("session opened in time")
        .expect("session")
}

/// A hub on a free port for mutual TLS: the endpoint others connect to.
pub fn hub_endpoint() -> String {
    protocol::access::secure_endpoint("127.0.0.1", free_port().unwrap())
}
