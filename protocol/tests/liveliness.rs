//! Membership watchers over real Zenoh sessions: a watcher dropped as soon as it has what it
//! waited for logs nothing about the events still on their way to it. Zenoh delivers on its
//! own threads and undeclares a dropped subscriber without waiting for a delivery in progress,
//! so a queue whose sending side logs "sending on a closed channel" (Zenoh's own FIFO handler
//! does) fails this test.
//!
//! Only the handlers' ERRORs count: a token declared and undeclared in a tight loop, as here,
//! also makes Zenoh's session log "Received Data for unknown expr_id" now and then, which is
//! its routing's own and which no component's membership changes fast enough to meet.

use std::sync::{Arc, Mutex};

use protocol::transport::{self, MemberEvent, Role, ZenohArgs};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, Layer, SubscriberExt};

/// How many times a watcher is made and dropped.
const WATCHES: usize = 200;
const ROBOTS: [&str; 3] = ["r1", "r2", "r3"];
/// Where Zenoh's handlers (the channels under a subscriber) log.
const HANDLERS: &str = "zenoh::api::handlers";

/// The ERROR events logged anywhere in the process, as their target and fields.
struct Errors(Arc<Mutex<Vec<String>>>);

impl<S: Subscriber> Layer<S> for Errors {
    fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
        if *event.metadata().level() == Level::ERROR {
            let mut fields = Fields(String::new());
            event.record(&mut fields);
            let line = format!("{}: {}", event.metadata().target(), fields.0);
            self.0.lock().unwrap_or_else(|e| e.into_inner()).push(line);
        }
    }
}

struct Fields(String);

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        self.0 += &format!("{}={value:?} ", field.name());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_watcher_dropped_after_the_members_it_waited_for_logs_no_error() {
    let errors = Arc::new(Mutex::new(Vec::new()));
    let logs = tracing_subscriber::registry()
        .with(Errors(errors.clone()).with_filter(tracing_subscriber::filter::LevelFilter::ERROR));
    tracing::subscriber::set_global_default(logs).expect("the only subscriber of this test");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let hub = format!("tcp/127.0.0.1:{port}");
    let members = transport::open(&ZenohArgs::listening(&hub), Role::Hub).await.expect("hub");
    let session =
        transport::open(&ZenohArgs::connecting(&hub), Role::Member).await.expect("member");
    let mut tokens = Vec::new();
    for r in ROBOTS {
        tokens.push(transport::declare_member(&members, "team", r).await.expect("token"));
    }
    // A robot that comes and goes all the while: its events are in flight when a watcher drops.
    let members = Arc::new(members);
    let churn = tokio::spawn({
        let members = members.clone();
        async move {
            loop {
                let t = transport::declare_member(&members, "team", "r4").await.expect("token");
                tokio::task::yield_now().await;
                drop(t);
            }
        }
    });
    for _ in 0..WATCHES {
        let watch = transport::watch_members(&session, "team").await.expect("watch");
        let mut present = Vec::new();
        while present.len() < ROBOTS.len() {
            let sample =
                tokio::time::timeout(std::time::Duration::from_secs(5), watch.recv_async())
                    .await
                    .expect("every member within 5 s")
                    .expect("an open queue");
            if let Some(MemberEvent::Joined(r)) = MemberEvent::from_sample(&sample) {
                if !present.contains(&r) {
                    present.push(r);
                }
            }
        }
        drop(watch);
    }
    churn.abort();
    let _ = churn.await;
    drop(tokens);
    transport::close(session).await.expect("close");
    let members = Arc::into_inner(members).expect("the churn has ended");
    transport::close(members).await.expect("close");
    let errors = errors.lock().unwrap_or_else(|e| e.into_inner());
    let handlers: Vec<_> = errors.iter().filter(|e| e.starts_with(HANDLERS)).collect();
    assert!(handlers.is_empty(), "ERROR events logged by a handler: {handlers:#?}");
}
