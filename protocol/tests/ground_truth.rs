//! The GroundTruth message: round trip in both encodings (its wire form is JSON), kind 11, non-finite numbers and bad
//! ids refused.

use protocol::{
    decode, encode, from_json, to_json, BodyTruth, ContactTruth, GroundTruth, Header, LoopTiming,
    MessageKind, Pose,
};

fn sample() -> GroundTruth {
    GroundTruth {
        header: Header::new("t1", None, 42, 7),
        time: 0.042,
        object: Some(BodyTruth {
            name: "object".into(),
            pose: Pose::IDENTITY,
            twist: [0.1, 0.0, 0.0, 0.0, 0.0, 0.2],
        }),
        torsos: vec![BodyTruth {
            name: "r1".into(),
            pose: Pose { position: [-1.15, 0.0, 0.55], orientation: [1.0, 0.0, 0.0, 0.0] },
            twist: [0.0; 6],
        }],
        hand_contacts: vec![ContactTruth {
            robot: "r1".into(),
            body: "hand".into(),
            position: [-0.3, 0.0, 0.6],
            wrench: [40.0, 0.0, 4.9, 0.0, 0.0, 0.0],
        }],
        foot_contacts: vec![ContactTruth {
            robot: "r1".into(),
            body: "LF_SHANK".into(),
            position: [0.0; 3],
            wrench: [0.0, 0.0, 150.0, 0.0, 0.0, 0.0],
        }],
        hands: vec![BodyTruth {
            name: "r1".into(),
            pose: Pose { position: [-0.3, 0.0, 0.6], orientation: [1.0, 0.0, 0.0, 0.0] },
            twist: [0.0; 6],
        }],
        feet: vec![BodyTruth {
            name: "r1/LF_FOOT".into(),
            pose: Pose { position: [-0.8, 0.3, 0.03], orientation: [1.0, 0.0, 0.0, 0.0] },
            twist: [0.0; 6],
        }],
        loop_timing: vec![
            LoopTiming {
                robot: "r1".into(),
                latency_us: Some(412.5),
                applied_tick: Some(42),
                late: 0,
                gap_steps: 0,
            },
            LoopTiming {
                robot: "r2".into(),
                latency_us: None,
                applied_tick: Some(40),
                late: 1,
                gap_steps: 0,
            },
        ],
    }
}

#[test]
fn ground_truth_round_trips_and_is_kind_11() {
    let g = sample();
    let bytes = encode(&g).unwrap();
    // Tool-facing: JSON on the wire (its kind number stays 11).
    assert_eq!(<GroundTruth as protocol::Message>::WIRE, protocol::Wire::Json);
    assert_eq!(serde_json::from_slice::<serde_json::Value>(&bytes).unwrap()["header"]["tick"], 42);
    assert_eq!(MessageKind::GroundTruth as u8, 11);
    assert_eq!(decode::<GroundTruth>(&bytes).unwrap(), g);
    assert_eq!(from_json::<GroundTruth>(&to_json(&g).unwrap()).unwrap(), g);
}

#[test]
fn ground_truth_with_nan_or_bad_ids_is_refused() {
    let mut g = sample();
    g.hand_contacts[0].wrench[3] = f64::NAN;
    assert!(encode(&g).is_err());
    let mut g = sample();
    g.torsos[0].name = "a/b".into();
    assert!(encode(&g).is_err());
    let mut g = sample();
    g.object.as_mut().unwrap().pose.orientation = [2.0, 0.0, 0.0, 0.0];
    assert!(encode(&g).is_err());
    let mut g = sample();
    g.hands[0].pose.position[1] = f64::NAN;
    assert!(encode(&g).is_err());
    let mut g = sample();
    g.time = f64::INFINITY;
    assert!(encode(&g).is_err());
    // The loop's timing: a latency that is not a duration, torques from a tick still to come.
    for bad in [f64::NAN, -1.0, f64::INFINITY] {
        let mut g = sample();
        g.loop_timing[0].latency_us = Some(bad);
        assert!(encode(&g).unwrap_err().to_string().contains("latency_us"), "{bad}");
    }
    let mut g = sample();
    g.loop_timing[1].applied_tick = Some(43);
    assert!(encode(&g).unwrap_err().to_string().contains("applied_tick"));
    let mut g = sample();
    g.loop_timing[1].robot = "r 2".into();
    assert!(encode(&g).is_err());
}

#[test]
fn ground_truth_without_loop_timing_still_decodes() {
    // Recordings made before the field existed (and lockstep runs) have none.
    let mut v = serde_json::to_value(sample()).unwrap();
    v.as_object_mut().unwrap().remove("loop_timing");
    let g: GroundTruth = serde_json::from_value(v).unwrap();
    assert!(g.loop_timing.is_empty());
}
