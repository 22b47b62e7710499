//! The binary layout written in `protocol/WIRE.md` is the one on the wire: the document's
//! worked example, built byte by byte from the document, equals what `encode` produces; and
//! the tool-facing types travel as plain JSON.

use protocol::{
    decode, encode, CoordinatorMode, CoordinatorStatus, Header, Message, Pose, RobotState, Wire,
};

fn f(x: f64) -> [u8; 8] {
    x.to_le_bytes()
}

#[test]
fn robot_state_bytes_are_the_documented_ones() {
    let s = RobotState {
        header: Header {
            version: 6,
            team: "t".into(),
            robot: Some("r1".into()),
            tick: 300,
            stamp_ns: 0,
        },
        base_pose: Pose { position: [1.0, 2.0, 3.0], orientation: [1.0, 0.0, 0.0, 0.0] },
        base_twist: [0.0; 6],
        joint_positions: vec![0.5],
        joint_velocities: vec![-0.25],
        time: 0.3,
        foot_forces: vec![120.0],
        object_pose: None,
    };
    let mut want: Vec<u8> = vec![0x54, 0x51, 0x06, 0x00, 0x01, 0x00];
    want.extend([0x06, 0x01, 0x74, 0x01, 0x02, 0x72, 0x31, 0xFB, 0x2C, 0x01, 0x00]);
    for x in [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] {
        want.extend(f(x));
    }
    want.push(0x01);
    want.extend(f(0.5));
    assert_eq!(&f(0.5), &[0, 0, 0, 0, 0, 0, 0xE0, 0x3F]);
    want.push(0x01);
    want.extend(f(-0.25));
    want.extend(f(0.3));
    assert_eq!(&f(0.3), &[0x33, 0x33, 0x33, 0x33, 0x33, 0x33, 0xD3, 0x3F]);
    want.push(0x01);
    want.extend(f(120.0));
    assert_eq!(&f(120.0), &[0, 0, 0, 0, 0, 0, 0x5E, 0x40]);
    want.push(0x00);
    let got = encode(&s).unwrap();
    assert_eq!(got, want);
    assert_eq!(decode::<RobotState>(&want).unwrap(), s);
    assert_eq!(RobotState::WIRE, Wire::Binary);
}

#[test]
fn tool_facing_messages_are_json_with_the_version_checked() {
    let st = CoordinatorStatus {
        header: Header::new("t", None, 7, 0),
        mode: CoordinatorMode::Running,
        members: vec!["r1".into()],
        ticks: 7,
        commands_sent: 14,
        deadline_misses: 0,
        fallbacks: 0,
        detail: String::new(),
        stale: vec![],
        silent: vec!["r2".into()],
        late: vec![],
        reused_terms: 3,
        refused: 2,
        last_refusal: Some("dynamics terms on team/t/robot/r2/dynamics: sender mismatch".into()),
    };
    assert_eq!(CoordinatorStatus::WIRE, Wire::Json);
    let bytes = encode(&st).unwrap();
    let v: serde_json::Value = serde_json::from_slice(&bytes).expect("plain JSON on the wire");
    assert_eq!(
        (v["mode"].as_str(), v["ticks"].as_u64(), v["header"]["version"].as_u64()),
        (Some("Running"), Some(7), Some(6))
    );
    assert_eq!(decode::<CoordinatorStatus>(&bytes).unwrap(), st);
    assert_eq!(protocol::schema_id::<CoordinatorStatus>(), "team.CoordinatorStatus/v6");
    // A status from before the silent, stale and late lists (an old recording) still decodes.
    let mut old = v.clone();
    for k in ["stale", "silent", "late", "reused_terms"] {
        old.as_object_mut().unwrap().remove(k);
    }
    let back = decode::<CoordinatorStatus>(&serde_json::to_vec(&old).unwrap()).unwrap();
    assert!(back.silent.is_empty() && back.reused_terms == 0);
    // Another version is refused, not misread.
    let mut other = st.clone();
    other.header.version = 9;
    let bytes = serde_json::to_vec(&other).unwrap();
    assert!(matches!(
        decode::<CoordinatorStatus>(&bytes),
        Err(protocol::ProtocolError::VersionMismatch { found: 9, .. })
    ));
    // Garbage is an error, not a panic.
    assert!(decode::<CoordinatorStatus>(b"{\"header\": 3}").is_err());
    assert!(decode::<CoordinatorStatus>(b"\xff\xfe not json").is_err());
}

#[test]
fn torque_command_bytes_are_the_documented_ones() {
    // WIRE.md's TorqueCommand examples: a hold order, then one torque of 1.5 N m at a team
    // delay of 2 ticks.
    let head = [0x06, 0x01, 0x74, 0x01, 0x02, 0x72, 0x31, 0xFB, 0x2C, 0x01, 0x00];
    let hold = protocol::TorqueCommand::hold("t", "r1", 300);
    let mut want: Vec<u8> = vec![0x54, 0x51, 0x06, 0x00, 0x03, 0x00];
    want.extend(head);
    want.extend([0x00, 0x01, 0x00, 0x00]);
    assert_eq!(encode(&hold).unwrap(), want);
    assert_eq!(decode::<protocol::TorqueCommand>(&want).unwrap(), hold);
    let torques = protocol::TorqueCommand {
        tau: vec![1.5],
        hold: false,
        delay_ticks: 2,
        qdd: vec![-2.0],
        ..hold.clone()
    };
    let mut want: Vec<u8> = vec![0x54, 0x51, 0x06, 0x00, 0x03, 0x00];
    want.extend(head);
    want.push(0x01);
    want.extend(f(1.5));
    assert_eq!(&f(1.5), &[0, 0, 0, 0, 0, 0, 0xF8, 0x3F]);
    want.extend([0x00, 0x02, 0x01]);
    want.extend(f(-2.0));
    assert_eq!(&f(-2.0), &[0, 0, 0, 0, 0, 0, 0, 0xC0]);
    assert_eq!(encode(&torques).unwrap(), want);
    // A delay over the longest is refused.
    assert!(encode(&protocol::TorqueCommand {
        delay_ticks: protocol::MAX_TEAM_DELAY_TICKS + 1,
        ..torques.clone()
    })
    .is_err());
    // A hold order that carries torques is refused.
    assert!(encode(&protocol::TorqueCommand { hold: true, ..torques }).is_err());
}

#[test]
fn drive_command_bytes_are_the_documented_ones() {
    // WIRE.md's DriveCommand example: one joint, 1.5 N m, no gains.
    let drive = protocol::DriveCommand::torque("t", "r1", 300, vec![1.5]);
    let mut want: Vec<u8> = vec![0x54, 0x51, 0x06, 0x00, 0x0C, 0x00];
    want.extend([0x06, 0x01, 0x74, 0x01, 0x02, 0x72, 0x31, 0xFB, 0x2C, 0x01, 0x00]);
    want.push(0x01);
    want.extend(f(1.5));
    want.extend([0x00, 0x00, 0x00, 0x00]);
    want.extend([0x00, 0x00, 0x00]);
    assert_eq!(encode(&drive).unwrap(), want);
    assert_eq!(decode::<protocol::DriveCommand>(&want).unwrap(), drive);
    // Read as the kind a torque key carried in the first version, it is refused, not misread.
    assert!(decode::<protocol::TorqueCommand>(&want).is_err());
}
