//! Test hosts: the team's components on separate machines of one computer, as Linux network
//! namespaces joined by veth pairs to one bridge (`scripts/testhosts.sh` makes and removes
//! them; root needed). [`TestHosts`] is one such set for one run: a host per component name,
//! its address, packet loss (nftables), link failures and connection resets, and the command
//! line that starts a program on a host. The set is removed when dropped. Where namespaces
//! cannot be made ([`TestHosts::check`]), callers say so and run on loopback instead.

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};

use thiserror::Error;

/// Every call of the script ends within this (`timeout`), s.
const SCRIPT_TIMEOUT_S: u32 = 30;

/// Why test hosts could not be made or changed.
#[derive(Debug, Error)]
pub enum HostsError {
    #[error("test hosts: {0}")]
    Unavailable(String),
    #[error("test hosts: `{args}` failed: {reason}")]
    Script { args: String, reason: String },
    #[error("test hosts: no host {0} in the set")]
    UnknownHost(String),
    #[error("test hosts: certificates from {dir}: {reason}")]
    Certificates { dir: String, reason: String },
}

/// The script: `TEAM_TESTHOSTS_SCRIPT`, else the repository's `scripts/testhosts.sh`.
fn script() -> PathBuf {
    repo_script("TEAM_TESTHOSTS_SCRIPT", "testhosts.sh")
}

/// The certificate script: `TEAM_CERTS_SCRIPT`, else the repository's
/// `scripts/make-test-certs.sh`.
fn cert_script() -> PathBuf {
    repo_script("TEAM_CERTS_SCRIPT", "make-test-certs.sh")
}

/// The script named by the environment variable `var`, else the repository's `scripts/{file}`.
fn repo_script(var: &str, file: &str) -> PathBuf {
    std::env::var_os(var).map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts")).join(file)
    })
}

fn call(args: &[&str]) -> Result<String, HostsError> {
    call_script(&script(), args)
}

/// `testhosts.sh` answered `args` with `text` that does not parse.
fn unparsed(args: &[&str], text: &str, e: impl std::fmt::Display) -> HostsError {
    HostsError::Script { args: invocation(&script(), args), reason: format!("{text:?}: {e}") }
}

/// `script args...` as an error names it: the script's file name and its arguments.
fn invocation(script: &Path, args: &[&str]) -> String {
    let name = script
        .file_name()
        .map_or_else(|| script.display().to_string(), |n| n.to_string_lossy().to_string());
    format!("{name} {}", args.join(" "))
}

/// Run `script` with `args` under `timeout`; its stdout, or why it failed.
fn call_script(script: &Path, args: &[&str]) -> Result<String, HostsError> {
    let joined = invocation(script, args);
    let out = Command::new("timeout")
        .arg(SCRIPT_TIMEOUT_S.to_string())
        .arg(script)
        .args(args)
        .output()
        .map_err(|e| HostsError::Script {
            args: joined.clone(),
            reason: format!("cannot start {}: {e}", script.display()),
        })?;
    if !out.status.success() {
        let reason = String::from_utf8_lossy(&out.stderr).trim().to_string();
        return Err(HostsError::Script {
            args: joined,
            reason: if reason.is_empty() { out.status.to_string() } else { reason },
        });
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// A set of test hosts (see the module docs).
#[derive(Debug)]
pub struct TestHosts {
    set: String,
    /// The bridge's address, in the namespace that made the set.
    gateway: Ipv4Addr,
    addrs: BTreeMap<String, Ipv4Addr>,
}

impl TestHosts {
    /// Whether namespaces, veth pairs and nftables work here (root, iproute2, nftables); the
    /// reason if not.
    pub fn check() -> Result<(), HostsError> {
        call(&["check"]).map(|_| ()).map_err(|e| match e {
            HostsError::Script { reason, .. } => HostsError::Unavailable(reason),
            other => other,
        })
    }

    /// Make one host per name, with a set name and network of their own (several sets may
    /// exist at once: one per run or test).
    pub fn up(names: &[String]) -> Result<TestHosts, HostsError> {
        static COUNTER: AtomicU32 = AtomicU32::new(0);
        let n = std::process::id()
            .wrapping_mul(64)
            .wrapping_add(COUNTER.fetch_add(1, Ordering::Relaxed))
            % (36 * 36 * 36 * 36);
        let set = format!("h{}", radix36(n, 4));
        let net = format!("10.{}.{}", 100 + n % 100, (n / 100) % 250);
        let mut args = vec!["up", set.as_str(), net.as_str()];
        args.extend(names.iter().map(String::as_str));
        call(&args)?;
        let gateway = format!("{net}.1").parse().map_err(|e| HostsError::Script {
            args: invocation(&script(), &args),
            reason: format!("network {net}: {e}"),
        })?;
        let mut hosts = TestHosts { set, gateway, addrs: BTreeMap::new() };
        for name in names {
            let text = call(&["addr", &hosts.set, name])?;
            let addr = text.parse().map_err(|e| unparsed(&["addr", &hosts.set, name], &text, e))?;
            hosts.addrs.insert(name.clone(), addr);
        }
        tracing::info!(set = %hosts.set, %net, hosts = ?hosts.addrs, "test hosts up");
        Ok(hosts)
    }

    /// The host's address.
    pub fn addr(&self, name: &str) -> Result<Ipv4Addr, HostsError> {
        self.addrs.get(name).copied().ok_or_else(|| HostsError::UnknownHost(name.to_string()))
    }

    /// Zenoh arguments of a component on `host` (`None`: this process, on the bridge) that
    /// connects to `hub`: it listens on its own address, so that the peers it meets through
    /// gossip can connect to it directly.
    pub fn zenoh_args(
        &self,
        host: Option<&str>,
        hub: &str,
    ) -> Result<protocol::transport::ZenohArgs, HostsError> {
        let addr = self.listen_addr(host)?;
        Ok(protocol::transport::ZenohArgs {
            listen: vec![format!("tcp/{addr}:0")],
            connect: vec![hub.to_string()],
            ..Default::default()
        })
    }

    /// Where a component on `host` listens: the host's address, or the bridge's for this
    /// process (`None`).
    pub fn listen_addr(&self, host: Option<&str>) -> Result<Ipv4Addr, HostsError> {
        match host {
            Some(h) => self.addr(h),
            None => Ok(self.gateway),
        }
    }

    /// Certificates for a run of `robots` on these hosts, into `out` (made anew): the test
    /// CA of `ca` ([`TestHosts::check_ca`]) signs one certificate per identity naming every
    /// host's address and the bridge's (`make-test-certs.sh --ca CA --san IP:...`), since a TLS
    /// client checks the address it connects to against the certificate. The hosts' addresses
    /// are chosen per set, so the certificates are too. The CA's key stays in `ca`: `out` gets
    /// a copy of `ca.pem` only.
    pub fn issue_certs(&self, ca: &Path, robots: &[String], out: &Path) -> Result<(), HostsError> {
        TestHosts::check_ca(ca)?;
        let certs =
            |reason: String| HostsError::Certificates { dir: ca.display().to_string(), reason };
        if out.exists() {
            let (ca_abs, out_abs) = (ca.canonicalize(), out.canonicalize());
            if let (Ok(c), Ok(o)) = (&ca_abs, &out_abs) {
                if c.starts_with(o) {
                    return Err(certs(format!(
                        "{} is where the run's certificates go (it is made anew); \
                         keep the CA elsewhere",
                        out.display()
                    )));
                }
            }
            std::fs::remove_dir_all(out)
                .map_err(|e| certs(format!("removing {}: {e}", out.display())))?;
        }
        let mut args: Vec<String> = vec!["--ca".into(), ca.display().to_string()];
        for addr in std::iter::once(&self.gateway).chain(self.addrs.values()) {
            args.extend(["--san".to_string(), format!("IP:{addr}")]);
        }
        args.push(out.display().to_string());
        args.extend(robots.iter().cloned());
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        call_script(&cert_script(), &args).map_err(|e| certs(e.to_string()))?;
        Ok(())
    }

    /// Whether `ca` holds a CA that can sign a run's certificates (`ca.pem` and `ca.key`, as
    /// `scripts/make-test-certs.sh DIR` makes them); checked before any host is made.
    pub fn check_ca(ca: &Path) -> Result<(), HostsError> {
        for f in ["ca.pem", "ca.key"] {
            if !ca.join(f).is_file() {
                let reason = format!(
                    "no {f}: test hosts over TLS need the test CA's certificate and key to sign \
                     certificates for the hosts' addresses (scripts/make-test-certs.sh DIR \
                     makes them)"
                );
                return Err(HostsError::Certificates { dir: ca.display().to_string(), reason });
            }
        }
        Ok(())
    }

    /// The host's network namespace.
    pub fn namespace(&self, name: &str) -> Result<String, HostsError> {
        self.addr(name).map(|_| format!("{}-{name}", self.set))
    }

    /// A command that runs `program` on the host (`ip netns exec`).
    pub fn command(&self, name: &str, program: &std::path::Path) -> Result<Command, HostsError> {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.namespace(name)?]).arg(program);
        Ok(c)
    }

    /// Drop `percent` % of the packets entering and leaving the host (0: none).
    pub fn set_loss(&self, name: &str, percent: u8) -> Result<(), HostsError> {
        self.addr(name)?;
        call(&["loss", &self.set, name, &percent.to_string()]).map(|_| ())
    }

    /// Packets the host's loss rule dropped so far.
    pub fn dropped(&self, name: &str) -> Result<u64, HostsError> {
        self.addr(name)?;
        let args = ["dropped", self.set.as_str(), name];
        let text = call(&args)?;
        text.parse().map_err(|e| unparsed(&args, &text, e))
    }

    /// Reset the host's TCP connections to host `peer` (both ends see them drop; Zenoh
    /// reconnects). Returns how many were cut.
    pub fn cut(&self, name: &str, peer: &str) -> Result<u32, HostsError> {
        self.addr(name)?;
        self.addr(peer)?;
        let args = ["cut", self.set.as_str(), name, peer];
        let text = call(&args)?;
        text.parse().map_err(|e| unparsed(&args, &text, e))
    }

    /// Take the host's link up or down.
    pub fn set_link(&self, name: &str, up: bool) -> Result<(), HostsError> {
        self.addr(name)?;
        call(&["link", &self.set, name, if up { "up" } else { "down" }]).map(|_| ())
    }
}

impl Drop for TestHosts {
    fn drop(&mut self) {
        if let Err(e) = call(&["down", &self.set]) {
            tracing::warn!("{e}");
        }
    }
}

fn radix36(mut n: u32, digits: usize) -> String {
    let mut out = vec![b'0'; digits];
    for d in out.iter_mut().rev() {
        *d = b"0123456789abcdefghijklmnopqrstuvwxyz"[(n % 36) as usize];
        n /= 36;
    }
    String::from_utf8(out).unwrap_or_default()
}
