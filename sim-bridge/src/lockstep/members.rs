//! Before the first tick: every robot a member of the team, and (if asked) the coordinator
//! ready to command them.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use protocol::keys;
use protocol::transport::{self, decode_sample, MemberEvent};
use tokio::sync::watch;
use zenoh::Session;

use super::config::{BridgeError, LockstepConfig};

/// Wait until every robot of `robots` has a liveliness token, or fail naming the missing ones.
pub(crate) async fn wait_for_members(
    session: &Session,
    cfg: &LockstepConfig,
    robots: &[String],
    stop: &watch::Receiver<bool>,
) -> Result<(), BridgeError> {
    let members_q = transport::watch_members(session, &cfg.team).await?;
    let status_q = if cfg.wait_for_coordinator {
        Some(transport::subscribe(session, keys::coordinator_status(&cfg.team)?).await?)
    } else {
        None
    };
    let started = Instant::now();
    let mut present = BTreeSet::new();
    while !robots.iter().all(|r| present.contains(r)) {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        let left = cfg.start_timeout.saturating_sub(started.elapsed());
        match tokio::time::timeout(left, members_q.recv_async()).await {
            Ok(Ok(sample)) => match MemberEvent::from_sample(&sample) {
                Some(MemberEvent::Joined(r)) => {
                    present.insert(r);
                }
                Some(MemberEvent::Left(r)) => {
                    present.remove(&r);
                }
                None => {}
            },
            _ => {
                let missing = robots.iter().filter(|r| !present.contains(*r)).cloned().collect();
                return Err(BridgeError::MembersMissing { missing, waited: cfg.start_timeout });
            }
        }
    }
    if let Some(q) = status_q {
        coordinator_ready(&q, robots, started, cfg.start_timeout, stop).await?;
    }
    Ok(())
}

/// Wait, until `timeout` after `started`, for a coordinator status on `q` that lists every robot
/// of `robots` as a member and is ready to command them; or fail with the last status heard.
pub(super) async fn coordinator_ready(
    q: &transport::SampleQueue,
    robots: &[String],
    started: Instant,
    timeout: Duration,
    stop: &watch::Receiver<bool>,
) -> Result<(), BridgeError> {
    let mut last = String::from("no status heard");
    loop {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        let left = timeout.saturating_sub(started.elapsed());
        match tokio::time::timeout(left, q.recv_async()).await {
            Ok(Ok(sample)) => {
                let Ok(st) = decode_sample::<protocol::CoordinatorStatus>(&sample) else {
                    continue;
                };
                let all = robots.iter().all(|r| st.members.contains(r));
                if all && st.mode != protocol::CoordinatorMode::WaitingForMembers {
                    return Ok(());
                }
                last = format!("members {:?}, mode {:?}: {}", st.members, st.mode, st.detail);
            }
            _ => return Err(BridgeError::CoordinatorNotReady { last, waited: timeout }),
        }
    }
}
