//! The one place every binary of the team sets up its log: `tracing` events on stderr.
//!
//! `RUST_LOG` wins when it is set; otherwise the binary's [`Verbosity`] chooses the level.
//! Zenoh's own INFO lines (its id, its endpoints, a session closing) show from
//! [`Verbosity::Debug`] on. [`directives`] gives what is in effect, so that a process started
//! by another (a distributed run's components) logs as its parent does.
//!
//! Colours only on a terminal. Two ERROR lines of Zenoh's router are dropped whatever the level
//! ([`ZenohNoise`]): they report an answer that arrives after the question was withdrawn, which
//! the router then ignores, and nothing is lost by it.

use std::fmt;
use std::io::IsTerminal;
use std::sync::OnceLock;

use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, Layer, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::EnvFilter;

/// The environment variable that overrides a binary's [`Verbosity`].
pub const LOG_ENV: &str = "RUST_LOG";

/// How much a binary logs when [`LOG_ENV`] does not say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    /// Errors only.
    Errors,
    /// Warnings and errors.
    Warnings,
    /// And what an operator follows: joins, leaves, safe mode, a run's phases.
    Info,
    /// And per-tick events, and Zenoh's INFO lines.
    Debug,
    /// Everything.
    Trace,
}

impl Verbosity {
    /// `--quiet` (errors only), or `Warnings` raised by one step per `-v`.
    pub fn from_flags(quiet: bool, verbose: u8) -> Self {
        match (quiet, verbose) {
            (true, _) => Verbosity::Errors,
            (false, 0) => Verbosity::Warnings,
            (false, 1) => Verbosity::Info,
            (false, 2) => Verbosity::Debug,
            (false, _) => Verbosity::Trace,
        }
    }

    /// The `tracing_subscriber::EnvFilter` directives of this level.
    pub fn directives(self) -> &'static str {
        match self {
            Verbosity::Errors => "error",
            Verbosity::Warnings => "warn",
            Verbosity::Info => "info,zenoh=warn",
            Verbosity::Debug => "debug,zenoh=info",
            Verbosity::Trace => "trace",
        }
    }
}

static DIRECTIVES: OnceLock<String> = OnceLock::new();

/// Log to stderr at [`LOG_ENV`]'s directives, or at `default`'s when it is unset or invalid.
/// Once per process; a second call changes nothing.
pub fn init(default: Verbosity) {
    let from_env = std::env::var(LOG_ENV).ok().filter(|d| EnvFilter::try_new(d).is_ok());
    let directives = from_env.unwrap_or_else(|| default.directives().to_string());
    if DIRECTIVES.set(directives.clone()).is_err() {
        return;
    }
    let _ = tracing_subscriber::registry()
        .with(EnvFilter::new(&directives))
        .with(ZenohNoise)
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(std::io::stderr().is_terminal()),
        )
        .try_init();
}

/// The directives [`init`] put in effect (`None` before it ran): the value of [`LOG_ENV`] for
/// a child process that should log as this one does.
pub fn directives() -> Option<&'static str> {
    DIRECTIVES.get().map(String::as_str)
}

/// Drops the ERROR events of Zenoh's router that report an answer arriving for something its
/// sender has withdrawn, which the router then ignores (Zenoh 1.10.2, `zenoh/src/net/routing`):
///
/// * `"Unknown interest"` (`hat/peer/interests.rs`, `route_declare_final` and
///   `route_current_token`; `hat/client/interests.rs`, `hat/broker/interests.rs`): a
///   declaration, or the final mark, answering an interest this router has withdrawn already.
///   A session sends an interest when it declares a publisher, a querier or a liveliness
///   subscriber, and withdraws it (`InterestMode::Final`) when that is undeclared; a peer's
///   answer still on its way then finds neither the interest nor its breadcrumb, and the
///   router returns `Noop`: the answer was for an entity that no longer exists.
/// * `"Route data with unknown scope N!"` (`dispatcher/pubsub.rs`, `route_data`): a sample
///   named by a key-expression id that its sending face no longer maps. A face's ids are
///   removed only when that face withdraws them (`UndeclareKeyExpr`, sent when the last
///   publisher or subscriber of the key in its session is dropped) or closes, so the sample
///   belongs to a publisher that is gone; the router drops it.
///
/// Every other event passes, Zenoh's other errors among them.
pub struct ZenohNoise;

/// Messages of [`ZenohNoise`], matched at the start of the text after the face's name.
const ZENOH_NOISE: [&str; 2] = ["Unknown interest", "Route data with unknown scope "];

impl<S: Subscriber> Layer<S> for ZenohNoise {
    fn event_enabled(&self, event: &Event<'_>, _ctx: Context<'_, S>) -> bool {
        let meta = event.metadata();
        if *meta.level() != Level::ERROR || !meta.target().starts_with("zenoh::net::routing") {
            return true;
        }
        let mut message = MessageText(String::new());
        event.record(&mut message);
        !is_zenoh_noise(&message.0)
    }
}

/// Whether a Zenoh router's error message is one [`ZenohNoise`] drops: one of
/// [`ZENOH_NOISE`], alone or after the face's name.
fn is_zenoh_noise(message: &str) -> bool {
    ZENOH_NOISE.iter().any(|m| message.starts_with(m) || message.contains(&format!(" {m}")))
}

/// The `message` field of an event, as text.
struct MessageText(String);

impl Visit for MessageText {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_choose_the_level() {
        assert_eq!(Verbosity::from_flags(true, 3), Verbosity::Errors);
        assert_eq!(Verbosity::from_flags(false, 0), Verbosity::Warnings);
        assert_eq!(Verbosity::from_flags(false, 1), Verbosity::Info);
        assert_eq!(Verbosity::from_flags(false, 2), Verbosity::Debug);
        assert_eq!(Verbosity::from_flags(false, 9), Verbosity::Trace);
        for v in [
            Verbosity::Errors,
            Verbosity::Warnings,
            Verbosity::Info,
            Verbosity::Debug,
            Verbosity::Trace,
        ] {
            assert!(EnvFilter::try_new(v.directives()).is_ok(), "{v:?}");
        }
    }

    #[test]
    fn only_the_withdrawn_answers_are_noise() {
        assert!(is_zenoh_noise("Unknown interest"));
        assert!(is_zenoh_noise("Face{1, 5f10…} Route data with unknown scope 12!"));
        assert!(!is_zenoh_noise("Face{1, 5f10…} Declare resource with unknown scope 12!"));
        assert!(!is_zenoh_noise("Unknown initial interest"));
        assert!(!is_zenoh_noise("Error treating timestamp for received Data"));
    }
}
