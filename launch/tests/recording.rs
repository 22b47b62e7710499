//! A recorded run read back with an independent reader (the `mcap` crate's, not the foxglove
//! SDK that wrote it): the channels are named after the Zenoh keys with JSON Schemas, the 3-D
//! view has Foxglove's well-known schemas, every tick's messages are there, nothing was
//! dropped, the chunks are zstd-compressed; and `team report run.mcap` (the replay) gives the
//! live run's metrics exactly.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use evaluation::evaluate;
use evaluation::plots;
use launch::record::{self, RecordOptions, ScenarioSource};
use launch::run::{self, RunOptions};
use scenario::file::Scenario;
use scenario::plan;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("repo root").to_path_buf()
}

/// Per topic: (schema name, schema encoding, message encoding, count).
fn channels(bytes: &[u8]) -> BTreeMap<String, (String, String, String, u64)> {
    let mut out: BTreeMap<String, (String, String, String, u64)> = BTreeMap::new();
    for m in mcap::MessageStream::new(bytes).expect("an MCAP file") {
        let m = m.expect("a readable message");
        let c = &m.channel;
        let (name, enc) =
            c.schema.as_ref().map(|s| (s.name.clone(), s.encoding.clone())).unwrap_or_default();
        out.entry(c.topic.clone()).or_insert((name, enc, c.message_encoding.clone(), 0)).3 += 1;
    }
    out
}

#[test]
fn a_recorded_run_reads_back_and_replays_to_the_same_metrics() {
    let file = repo().join("scenarios/s4_object_circle.toml");
    let sets = vec!["duration=0.3".to_string(), "settle=0.1".to_string()];
    let plan = plan::plan(&Scenario::load(&file, &sets).unwrap(), &repo()).unwrap();
    let dir = repo().join("target/test-reports/recording");
    std::fs::create_dir_all(&dir).unwrap();
    let rec = RecordOptions {
        path: dir.join("run.mcap"),
        scenario: ScenarioSource::read(&file, &sets, scenario::Pacing::Lockstep).unwrap(),
        live: None,
        split: None,
    };
    let (records, summary) = run::run_recorded(
        &plan,
        &RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() },
        &dir,
        Some(&rec),
    )
    .expect("the run completes");
    let summary = summary.expect("recorded");
    assert_eq!((summary.dropped, summary.failed), (0, 0), "{summary:?}");
    let live = evaluate::evaluate(&plan, &records, "embedded");

    let bytes = std::fs::read(dir.join("run.mcap")).unwrap();
    let ch = channels(&bytes);
    // The chunks are zstd-compressed, and it pays (S4's whole 10 s: 3.5 times smaller; the
    // floats' low digits are what is left).
    let summary = mcap::Summary::read(&bytes).expect("a summary").expect("an indexed file");
    assert!(!summary.chunk_indexes.is_empty());
    assert!(
        summary.chunk_indexes.iter().all(|c| c.compression == "zstd"),
        "{:?}",
        summary.chunk_indexes.iter().map(|c| &c.compression).collect::<Vec<_>>()
    );
    let (packed, plain): (u64, u64) = summary
        .chunk_indexes
        .iter()
        .fold((0, 0), |(p, u), c| (p + c.compressed_size, u + c.uncompressed_size));
    assert!(packed * 5 < plain * 2, "zstd chunks: {packed} bytes for {plain}");
    let total = plan.total_ticks();
    let json = |topic: &str, schema: &str| {
        let (name, enc, msg_enc, n) =
            ch.get(topic).unwrap_or_else(|| panic!("no channel {topic}: {:?}", ch.keys()));
        assert_eq!(
            (name.as_str(), enc.as_str(), msg_enc.as_str()),
            (schema, "jsonschema", "json"),
            "{topic}"
        );
        *n
    };
    assert_eq!(
        json("team/team/ground-truth", "team.GroundTruth"),
        total,
        "a ground truth per tick"
    );
    // References: one per tick (the driver sends its first window again once the coordinator
    // is heard of; the recording keeps the first).
    assert_eq!(json("team/team/references", "team.TaskReferences"), total);
    let mut ticks = std::collections::BTreeSet::new();
    for m in mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .filter(|m| m.channel.topic == "team/team/references")
    {
        ticks.insert(
            serde_json::from_slice::<protocol::TaskReferences>(&m.data).unwrap().header.tick,
        );
    }
    assert_eq!(ticks, (0..total).collect(), "a reference for every tick");
    let diagnostics = json("team/team/coordinator/diagnostics", "team.TickDiagnostics");
    assert!(
        diagnostics >= total - 2 && diagnostics <= total,
        "{diagnostics} diagnostics for {total} ticks"
    );
    json("team/team/coordinator/status", "team.CoordinatorStatus");
    for r in &plan.robots {
        let key = |t: &str| format!("team/team/robot/{}/{t}", r.id);
        assert_eq!(json(&key("state"), "team.RobotState"), total, "{} states", r.id);
        let per_tick = |n: u64| n + 2 >= total && n <= total + 1;
        let dynamics = json(&key("dynamics"), "team.DynamicsSummary");
        assert!(per_tick(dynamics), "{} dynamics for {total} ticks", dynamics);
        let commands = json(&key("command"), "team.TorqueCommand");
        assert!(per_tick(commands), "{commands} commands for {total} ticks");
        let torques = json(&key("torque"), "team.DriveCommand");
        assert!(per_tick(torques), "{torques} torques for {total} ticks");
    }
    // The 3-D view: Foxglove's well-known schemas, every 10th tick at 1 kHz.
    let every = (plan.scenario.control_hz / record::SCENE_HZ).round() as u64;
    for (topic, schema) in [("/tf", "foxglove.FrameTransforms"), ("/scene", "foxglove.SceneUpdate")]
    {
        let (name, enc, msg_enc, n) = &ch[topic];
        assert_eq!(
            (name.as_str(), enc.as_str(), msg_enc.as_str()),
            (schema, "protobuf", "protobuf")
        );
        assert_eq!(*n, total.div_ceil(every), "{topic}");
    }
    // One ground-truth message decodes as the type, from JSON.
    let truth = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .find(|m| m.channel.topic == "team/team/ground-truth")
        .unwrap();
    let g: protocol::GroundTruth = serde_json::from_slice(&truth.data).unwrap();
    assert_eq!(g.header.tick, 0);

    // Replay: the same metrics, to the last bit.
    let (plan2, records2, replayed) =
        record::replay::evaluate_recording(&dir.join("run.mcap"), &repo()).expect("replay");
    assert_eq!(
        serde_json::to_value(&replayed.metrics).unwrap(),
        serde_json::to_value(&live.metrics).unwrap()
    );
    assert_eq!(plan2.total_ticks(), total);
    evaluate::write_report(&plan2, &replayed, &dir).unwrap();
    plots::write_all(&plan2, &replayed, &records2, &dir).unwrap();
    for (stem, _) in plots::FIGURES {
        for ext in ["png", "svg"] {
            let f = dir.join(format!("{stem}.{ext}"));
            assert!(
                std::fs::metadata(&f).map(|m| m.len() > 1000).unwrap_or(false),
                "{}",
                f.display()
            );
        }
    }
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains("object_error.png") && html.contains(&plan.scenario.name));
}

/// A recording split into files of 512 KiB: every file an MCAP of its own with the run's
/// metadata and its segment number, `team report` over them all gives the live run's metrics,
/// and with a file gone it refuses with the reason.
#[test]
fn a_split_recording_replays_whole_and_one_with_a_file_gone_is_refused() {
    use record::segments::{segment_path, Split};
    let file = repo().join("scenarios/s4_object_circle.toml");
    let sets = vec!["duration=0.3".to_string(), "settle=0.1".to_string()];
    let plan = plan::plan(&Scenario::load(&file, &sets).unwrap(), &repo()).unwrap();
    let dir = repo().join("target/test-reports/recording-split");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("run.mcap");
    let rec = RecordOptions {
        path: path.clone(),
        scenario: ScenarioSource::read(&file, &sets, scenario::Pacing::Lockstep).unwrap(),
        live: None,
        split: Some(Split { bytes: 512 << 10, keep: None }),
    };
    let opts = RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() };
    let (records, summary) =
        run::run_recorded(&plan, &opts, &dir, Some(&rec)).expect("the run completes");
    let summary = summary.expect("recorded");
    assert_eq!((summary.dropped, summary.failed, summary.error), (0, 0, None));
    let live = evaluate::evaluate(&plan, &records, "embedded");
    let closed: Vec<PathBuf> =
        (1..).map(|k| segment_path(&path, k)).take_while(|p| p.exists()).collect();
    assert!(closed.len() >= 2, "split into several files: {closed:?}");
    assert_eq!(summary.segments, closed.len() as u64, "the summary counts the files");
    let on_disk: u64 =
        closed.iter().chain([&path]).map(|p| std::fs::metadata(p).unwrap().len()).sum();
    assert_eq!(summary.bytes, on_disk, "the summary's size is every file's");
    for (k, p) in closed.iter().enumerate() {
        let bytes = std::fs::read(p).unwrap();
        assert!(!channels(&bytes).is_empty(), "{} holds messages", p.display());
        let meta = mcap::read::LinearReader::new(&bytes)
            .unwrap()
            .filter_map(|r| match r.unwrap() {
                mcap::records::Record::Metadata(m) if m.name == record::RUN_METADATA => Some(m),
                _ => None,
            })
            .next()
            .expect("the run's metadata in every file");
        assert_eq!(meta.metadata["segment"], (k + 1).to_string());
        assert!(meta.metadata["scenario_text"].contains("object"));
    }
    let (_, _, replayed) = record::replay::evaluate_recording(&path, &repo()).expect("replay");
    assert_eq!(
        serde_json::to_value(&replayed.metrics).unwrap(),
        serde_json::to_value(&live.metrics).unwrap()
    );
    std::fs::remove_file(&closed[0]).unwrap();
    let err = record::replay::evaluate_recording(&path, &repo()).err().expect("refused");
    assert!(err.to_string().contains("[1] are gone"), "{err}");
}
