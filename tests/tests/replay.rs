//! Lockstep runs replay bit for bit: the same scenario run twice embedded, and once more with
//! every component its own process, gives byte-identical `timeseries.csv` and `torques.csv`,
//! and the same torques and ground truth to the last bit.
//!
//! What used to vary was the start: the coordinator could solve the first tick before the
//! scenario driver's first references reached it, and held the object where it measured it
//! instead of where the reference put it (1e-16 apart, 1e-11 at the end of the run). The driver
//! now sends the first references once the coordinator listens, before the first tick
//! (`Driver::send_first_window`); this test would see a run that raced.

mod common;

use evaluation::records::Records;

use common::scenario::{report_dir, run_scenario_records};

const SCENARIO: &str = "s4_object_circle.toml";
const SETS: [&str; 2] = ["duration=1", "settle=0.5"];

/// Every applied torque and every ground-truth pose of the run, as bits.
fn bits(r: &Records) -> Vec<u64> {
    let mut out = Vec::new();
    for series in r.torques.values() {
        for (tick, tau) in series {
            out.push(*tick);
            out.extend(tau.iter().map(|x| x.to_bits()));
        }
    }
    for gt in &r.truth {
        out.push(gt.header.tick);
        for body in gt.object.iter().chain(&gt.torsos).chain(&gt.hands).chain(&gt.feet) {
            out.extend(
                body.pose
                    .position
                    .iter()
                    .chain(&body.pose.orientation)
                    .chain(&body.twist)
                    .map(|x| x.to_bits()),
            );
        }
    }
    out
}

fn file(name: &str, f: &str) -> Vec<u8> {
    let path = report_dir(name).join(f);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn lockstep_runs_replay_bit_for_bit() {
    let (_, _, first) = run_scenario_records(SCENARIO, &SETS, false, "replay_first");
    let (_, _, second) = run_scenario_records(SCENARIO, &SETS, false, "replay_second");
    let (_, _, distributed) = run_scenario_records(SCENARIO, &SETS, true, "replay_distributed");
    let reference = bits(&first);
    assert!(
        reference.len() > 10_000,
        "the run recorded its torques and ground truth: {} values",
        reference.len()
    );
    for (name, run) in [("replay_second", &second), ("replay_distributed", &distributed)] {
        for f in ["timeseries.csv", "torques.csv"] {
            assert!(
                file("replay_first", f) == file(name, f),
                "{name}/{f} differs from replay_first/{f}"
            );
        }
        let other = bits(run);
        let first_diff = reference.iter().zip(&other).position(|(a, b)| a != b);
        assert!(reference.len() == other.len() && first_diff.is_none(), "{name}: the torques or the ground truth differ from the first run's (first at value {first_diff:?} of {})", reference.len());
    }
}
