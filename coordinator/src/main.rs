//! `coordinator`: solves the team problem every tick.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use coordinator::service::{self, CoordinatorConfig};
use coordinator::team::assembly::TermsReuse;
use coordinator::ControllerSpec;
use protocol::transport::{self, Role, ZenohArgs};

#[derive(Parser)]
#[command(version, about = "The team controller: gathers dynamics terms, sends torque slices")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the coordinator service.
    Run {
        /// Team id.
        #[arg(long, default_value = "team")]
        team: String,
        /// How long a tick may wait for every member's dynamics terms, ms.
        #[arg(long, default_value_t = 200)]
        tick_deadline_ms: u64,
        /// Team controller, with its default parameters: `pidc` (projected inverse dynamics
        /// with the contact-force QP; runs once every member's description is known),
        /// `mqp` (the paper's baseline, the multi-robot QP solved by Clarabel; likewise) or
        /// `joint-damping` (the smoke run). Without it and without --controller-config:
        /// joint-damping.
        #[arg(long, value_parser = parse_kind)]
        controller: Option<ControllerSpec>,
        /// Controller file (TOML): `kind = "pidc"`, `"mqp"` or `"joint-damping"` and the
        /// controller's parameters (see `ControllerSpec`). Enough alone; with --controller the
        /// kinds must agree.
        #[arg(long)]
        controller_config: Option<PathBuf>,
        /// Joint damping of the joint-damping controller, N·m·s/rad (default 2).
        #[arg(long, conflicts_with = "controller_config")]
        damping: Option<f64>,
        /// Real time: solve a tick this long (µs) after its first terms with a late member's
        /// latest terms, and leave out a member whose latest are more than
        /// --reuse-max-age ticks old (silent). Without it every tick waits for every member.
        #[arg(long, requires = "reuse_max_age")]
        reuse_after_us: Option<u64>,
        /// With --reuse-after-us: the oldest terms reused, in ticks.
        #[arg(long, requires = "reuse_after_us")]
        reuse_max_age: Option<u64>,
        /// The team's robots (comma-separated): the first tick waits until all have joined, at
        /// most 3 s (a restarted coordinator meets its agents one by one).
        #[arg(long, value_delimiter = ',')]
        expect: Vec<String>,
        /// The robots' control rate, Hz (the agents' own: a wrong rate scales every
        /// prediction): with a team delay, each robot's state is carried over the commands
        /// still in flight before its tick is solved. Without it, each command answers the
        /// state as measured.
        #[arg(long)]
        robot_hz: Option<f64>,
        /// A planner sends the task references: every robot holds its posture until the first
        /// came, at most this many milliseconds from the start (0: solve at once, each task held
        /// where it is until references name it).
        #[arg(long, default_value_t = 0)]
        wait_for_references_ms: u64,
        /// Real time: a tick's solve may take this long (µs) before the controller's fallback
        /// answers (the steps after the first QP that would run past it are not started).
        /// Without it every tick is solved to its end, however long that takes.
        #[arg(long)]
        solve_budget_us: Option<u64>,
        #[command(flatten)]
        zenoh: ZenohArgs,
    },
}

fn parse_kind(kind: &str) -> Result<ControllerSpec, String> {
    ControllerSpec::of_kind(kind).map_err(|e| e.to_string())
}

/// The controller the flags choose (see `Command::Run`).
fn controller_spec(
    kind: Option<ControllerSpec>,
    file: Option<&Path>,
    damping: Option<f64>,
) -> Result<ControllerSpec> {
    let mut spec = match (kind, file) {
        (kind, Some(path)) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            let spec = ControllerSpec::from_toml(&text)
                .with_context(|| format!("controller file {}", path.display()))?;
            if let Some(k) = kind {
                anyhow::ensure!(
                    k.kind() == spec.kind(),
                    "--controller {} but {} has kind = \"{}\"",
                    k.kind(),
                    path.display(),
                    spec.kind()
                );
            }
            spec
        }
        (Some(spec), None) => spec,
        (None, None) => ControllerSpec::of_kind("joint-damping")?,
    };
    if let Some(d) = damping {
        match &mut spec {
            ControllerSpec::JointDamping(c) => c.damping = d,
            other => anyhow::bail!(
                "--damping is the joint-damping controller's; {} takes its parameters from \
                 --controller-config",
                other.kind()
            ),
        }
    }
    spec.check()?;
    Ok(spec)
}

#[tokio::main]
async fn main() -> Result<()> {
    protocol::logging::init(protocol::logging::Verbosity::Info);
    match Cli::parse().command {
        Command::Run {
            team,
            tick_deadline_ms,
            controller,
            controller_config,
            damping,
            reuse_after_us,
            reuse_max_age,
            expect,
            robot_hz,
            wait_for_references_ms,
            solve_budget_us,
            zenoh,
        } => {
            anyhow::ensure!(
                robot_hz.is_none_or(|hz| hz.is_finite() && hz > 0.0),
                "--robot-hz must be a positive rate in Hz, not {robot_hz:?}"
            );
            let controller =
                controller_spec(controller, controller_config.as_deref(), damping)?.build()?;
            let session = transport::open(&zenoh, Role::Hub).await?;
            let reuse = reuse_after_us
                .zip(reuse_max_age)
                .map(|(us, max_age)| TermsReuse { after: Duration::from_micros(us), max_age });
            for r in &expect {
                protocol::validate_id("robot", r).map_err(|e| anyhow::anyhow!("--expect: {e}"))?;
            }
            let cfg = CoordinatorConfig {
                team,
                tick_deadline: Duration::from_millis(tick_deadline_ms),
                reuse,
                expected: expect,
                robot_hz,
                wait_for_references: (wait_for_references_ms > 0)
                    .then(|| Duration::from_millis(wait_for_references_ms)),
                solve_budget: solve_budget_us.map(Duration::from_micros),
            };
            let (tx, rx) = tokio::sync::watch::channel(false);
            tokio::spawn(async move {
                let _ = tokio::signal::ctrl_c().await;
                let _ = tx.send(true);
            });
            service::run(&session, cfg, controller, rx).await?;
            protocol::transport::close(session).await?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use coordinator::joint_damping::JointDampingConfig;

    fn file(name: &str, text: &str) -> PathBuf {
        let path =
            std::env::temp_dir().join(format!("coordinator-{}-{name}.toml", std::process::id()));
        std::fs::write(&path, text).expect("temp file");
        path
    }

    #[test]
    fn one_way_to_choose_the_controller_and_clear_errors() {
        // Neither flag: joint damping (the smoke run); --damping sets it.
        assert_eq!(
            controller_spec(None, None, None).unwrap(),
            ControllerSpec::JointDamping(JointDampingConfig { damping: 2.0 })
        );
        assert_eq!(
            controller_spec(None, None, Some(0.5)).unwrap(),
            ControllerSpec::JointDamping(JointDampingConfig { damping: 0.5 })
        );
        // A kind alone: its defaults.
        let pidc = parse_kind("pidc").unwrap();
        assert_eq!(controller_spec(Some(pidc.clone()), None, None).unwrap(), pidc);
        let e = parse_kind("paper").unwrap_err();
        assert!(e.contains("now `pidc`") && e.contains("pidc, joint-damping"), "{e}");
        // A file alone is enough; with --controller the kinds must agree.
        let path = file("pidc", "kind = \"pidc\"\nf_min_hand = 12.0\n");
        let ControllerSpec::Pidc(c) = controller_spec(None, Some(&path), None).unwrap() else {
            panic!("pidc file")
        };
        assert_eq!(c.f_min_hand, 12.0);
        assert!(controller_spec(Some(pidc.clone()), Some(&path), None).is_ok());
        let e = controller_spec(Some(parse_kind("joint-damping").unwrap()), Some(&path), None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--controller joint-damping but") && e.contains("kind = \"pidc\""),
            "{e}"
        );
        // --damping belongs to joint damping.
        let e = controller_spec(Some(pidc), None, Some(1.0)).unwrap_err().to_string();
        assert!(e.contains("--damping"), "{e}");
        assert!(controller_spec(None, None, Some(-1.0)).is_err());
        // A broken file names itself.
        let bad = file("bad", "kind = \"pidc\"\nf_min_hnad = 1.0\n");
        let e = format!("{:#}", controller_spec(None, Some(&bad), None).unwrap_err());
        assert!(e.contains(&bad.display().to_string()) && e.contains("f_min_hnad"), "{e}");
        // The baseline: by kind, or by file with any of its fields.
        assert_eq!(
            controller_spec(Some(parse_kind("mqp").unwrap()), None, None).unwrap(),
            ControllerSpec::Mqp(coordinator::MqpConfig::default())
        );
        let mqp = file("mqp", "kind = \"mqp\"\nobject_weight = 3.0\n");
        let ControllerSpec::Mqp(m) = controller_spec(None, Some(&mqp), None).unwrap() else {
            panic!("mqp file")
        };
        assert_eq!(m.object_weight, 3.0);
        assert!(controller_spec(None, Some(&mqp), None)
            .unwrap()
            .build()
            .unwrap()
            .name()
            .starts_with("mqp"));
        let _ = std::fs::remove_file(path);
        let _ = std::fs::remove_file(bad);
        let _ = std::fs::remove_file(mqp);
    }
}
