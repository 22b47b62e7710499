//! Decoding never panics and says what is wrong: random bytes, truncated and oversized
//! payloads, wrong versions, NaN and infinity, mismatched dimensions.

use proptest::prelude::*;
use protocol::codec::encode_into;
use protocol::*;

fn header(robot: bool) -> Header {
    Header::new("team1", robot.then_some("r1"), 42, 1_000_000)
}

fn state(nj: usize) -> RobotState {
    RobotState {
        header: header(true),
        base_pose: Pose { position: [0.1, 0.2, 0.5], orientation: [1.0, 0.0, 0.0, 0.0] },
        base_twist: [0.0, 0.1, 0.0, 0.0, 0.0, 0.2],
        joint_positions: (0..nj).map(|i| i as f64 * 0.1).collect(),
        joint_velocities: vec![0.01; nj],
        time: 0.5,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

fn frame(name: &str, role: FrameRole, nv: usize) -> FrameTerms {
    let d = role.dim();
    FrameTerms {
        name: name.into(),
        role,
        position: [0.3, 0.0, 0.0],
        rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        jacobian: Matrix {
            rows: d as u32,
            cols: nv as u32,
            data: (0..d * nv).map(|i| (i as f64 * 0.7).sin()).collect(),
        },
        jdot_v: vec![0.5; d],
    }
}

fn dynamics(nv: usize) -> DynamicsTerms {
    let mut m = Matrix::zeros(nv, nv);
    for i in 0..nv {
        for j in 0..nv {
            m.data[i * nv + j] =
                if i == j { 1.0 + i as f64 / 3.0 } else { 0.01 * ((i * nv + j) as f64).cos() };
        }
    }
    DynamicsTerms {
        header: header(true),
        floating_base: true,
        nv: nv as u32,
        mass_matrix: m,
        bias: vec![9.81; nv],
        velocity: vec![0.0; nv],
        frames: vec![
            frame("LF_FOOT", FrameRole::StanceFoot, nv),
            frame("hand_contact", FrameRole::Hand, nv),
            frame("base", FrameRole::Torso, nv),
        ],
        hand_in_grasp: true,
        state_tick: 42,
        team_delay_ticks: 0,
        object_pose: None,
    }
}

fn command(n: usize) -> TorqueCommand {
    TorqueCommand {
        header: header(true),
        tau: vec![1.5; n],
        hold: false,
        delay_ticks: 0,
        qdd: Vec::new(),
    }
}

fn raw<M: Message>(m: &M) -> Vec<u8> {
    let mut out = Vec::new();
    encode_into(m, &mut out).unwrap();
    out
}

#[test]
fn valid_messages_round_trip_in_both_encodings() {
    let s = state(18);
    assert_eq!(decode::<RobotState>(&encode(&s).unwrap()).unwrap(), s);
    assert_eq!(from_json::<RobotState>(&to_json(&s).unwrap()).unwrap(), s);
    let d = dynamics(24);
    assert_eq!(decode::<DynamicsTerms>(&encode(&d).unwrap()).unwrap(), d);
    assert_eq!(from_json::<DynamicsTerms>(&to_json(&d).unwrap()).unwrap(), d);
    let c = command(18);
    assert_eq!(decode::<TorqueCommand>(&encode(&c).unwrap()).unwrap(), c);
}

#[test]
fn binary_is_compact() {
    // A 24-DoF dynamics message: the numbers alone are 8 bytes each.
    let d = dynamics(24);
    let numbers = 24 * 24 + 24 + 24 + 3 * (3 + 9) + (3 + 6 + 6) * 24 + 3 + 6 + 6;
    let bytes = encode(&d).unwrap().len();
    assert!(bytes < numbers * 8 + 200, "{bytes} bytes for {numbers} numbers");
    // The same message printed as JSON is much larger.
    assert!(to_json(&d).unwrap().len() > 2 * bytes);
}

#[test]
fn wrong_version_kind_and_magic_are_named() {
    let mut b = encode(&state(3)).unwrap();
    b[2] = 99;
    assert!(matches!(
        decode::<RobotState>(&b),
        Err(ProtocolError::VersionMismatch { found: 99, .. })
    ));
    let b = encode(&state(3)).unwrap();
    assert!(matches!(decode::<TorqueCommand>(&b), Err(ProtocolError::WrongKind { .. })));
    let mut b = encode(&state(3)).unwrap();
    b[0] = b'X';
    assert!(matches!(decode::<RobotState>(&b), Err(ProtocolError::BadMagic { .. })));
    let mut s = state(3);
    s.header.version = 7;
    let json = serde_json::to_string(&s).unwrap();
    assert!(matches!(
        from_json::<RobotState>(&json),
        Err(ProtocolError::VersionMismatch { found: 7, .. })
    ));
}

#[test]
fn every_truncation_is_an_error() {
    let b = encode(&dynamics(8)).unwrap();
    for n in 0..b.len() {
        assert!(decode::<DynamicsTerms>(&b[..n]).is_err(), "prefix of {n} bytes accepted");
    }
}

#[test]
fn trailing_and_oversized_payloads_are_rejected() {
    let mut b = encode(&command(4)).unwrap();
    b.push(0);
    assert!(matches!(decode::<TorqueCommand>(&b), Err(ProtocolError::Malformed { .. })));
    let huge = vec![0u8; MAX_MESSAGE_BYTES + 1];
    assert!(matches!(decode::<TorqueCommand>(&huge), Err(ProtocolError::Oversized { .. })));
    // A length prefix that claims 2^62 entries must not allocate them.
    let mut b = encode(&command(1)).unwrap();
    let tau_len_at = b.len() - 9; // varint length 1 byte + one f64
    b.truncate(tau_len_at);
    b.push(255); // varint marker for a u64 follows
    b.extend_from_slice(&(1u64 << 62).to_le_bytes());
    assert!(decode::<TorqueCommand>(&b).is_err());
}

#[test]
fn non_finite_numbers_are_named() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut c = command(5);
        c.tau[3] = bad;
        assert!(encode(&c).is_err(), "encode validates");
        match decode::<TorqueCommand>(&raw(&c)) {
            Err(ProtocolError::NonFinite { field, index, .. }) => {
                assert_eq!((field.as_str(), index), ("tau", 3))
            }
            other => panic!("expected NonFinite, got {other:?}"),
        }
        let mut d = dynamics(8);
        d.frames[1].jacobian.data[7] = bad;
        assert!(matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::NonFinite { .. })));
        let json = serde_json::to_string(&d).unwrap(); // serde_json writes NaN as null
        assert!(from_json::<DynamicsTerms>(&json).is_err());
    }
}

/// A command's accelerations: one per torque or none, finite, never on a hold order; a
/// command with them reads back as it was.
#[test]
fn a_commands_accelerations_are_checked() {
    let mut c = command(3);
    c.qdd = vec![0.5, -1.0, 2.0];
    assert_eq!(decode::<TorqueCommand>(&encode(&c).unwrap()).unwrap(), c);
    let mut short = c.clone();
    short.qdd.pop();
    assert!(
        matches!(decode::<TorqueCommand>(&raw(&short)), Err(ProtocolError::Invalid { field, .. }) if field == "qdd")
    );
    let mut nan = c.clone();
    nan.qdd[1] = f64::NAN;
    match decode::<TorqueCommand>(&raw(&nan)) {
        Err(ProtocolError::NonFinite { field, index, .. }) => {
            assert_eq!((field.as_str(), index), ("qdd", 1))
        }
        other => panic!("expected NonFinite, got {other:?}"),
    }
    let mut hold = TorqueCommand::hold("t", "r1", 3);
    hold.qdd = vec![1.0];
    assert!(decode::<TorqueCommand>(&raw(&hold)).is_err(), "a hold order moves nothing");
}

#[test]
fn mismatched_dimensions_are_named() {
    let mut d = dynamics(8);
    d.mass_matrix.data.pop();
    assert!(matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::Dimension { .. })));
    let mut d = dynamics(8);
    d.bias.push(0.0);
    assert!(
        matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::Dimension { field, .. }) if field == "bias")
    );
    let mut d = dynamics(8);
    d.frames[0] = frame("LF_FOOT", FrameRole::StanceFoot, 9);
    assert!(matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::Dimension { .. })));
    let mut d = dynamics(8);
    d.frames[1].jdot_v.truncate(3);
    assert!(matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::Dimension { .. })));
    let mut s = state(4);
    s.joint_velocities.pop();
    assert!(matches!(decode::<RobotState>(&raw(&s)), Err(ProtocolError::Dimension { .. })));
    let mut s = state(4);
    s.base_pose.orientation = [0.5, 0.0, 0.0, 0.0];
    assert!(matches!(decode::<RobotState>(&raw(&s)), Err(ProtocolError::Invalid { .. })));
    let mut s = state(4);
    s.header.robot = Some("r/1".into());
    assert!(matches!(decode::<RobotState>(&raw(&s)), Err(ProtocolError::BadId { .. })));
    // Foot forces: pushing only, finite, bounded in count.
    for bad in [vec![-1.0, 0.0, 0.0, 0.0], vec![f64::NAN], vec![0.0; 17]] {
        let mut s = state(4);
        s.foot_forces = bad;
        assert!(
            decode::<RobotState>(&raw(&s)).is_err(),
            "foot forces {:?} accepted",
            s.foot_forces
        );
    }
    let mut s = state(4);
    s.foot_forces = vec![0.0, 120.0, 95.5, 3.0];
    assert_eq!(decode::<RobotState>(&raw(&s)).unwrap(), s);
}

#[test]
fn foot_loads_must_bound_a_pushing_force() {
    let refs = |f: f64| TaskReferences {
        header: Header::new("t", None, 3, 0),
        object: None,
        torsos: vec![],
        swing_feet: vec![],
        foot_loads: vec![FootLoad {
            robot: "r1".into(),
            frame: "LF_FOOT".into(),
            max_normal_force: f,
        }],
    };
    assert!(from_json::<TaskReferences>(&to_json(&refs(40.0)).unwrap()).is_ok());
    for bad in [-1.0, f64::INFINITY] {
        assert!(to_json(&refs(bad)).is_err(), "bound {bad} sent");
        let text = serde_json::to_string(&refs(bad)).unwrap();
        assert!(from_json::<TaskReferences>(&text).is_err(), "bound {bad} accepted");
    }
    // A sender that leaves the field out: no foot is being unloaded.
    let old = r#"{"header":{"version":6,"team":"t","robot":null,"tick":3,"stamp_ns":0},"object":null,"torsos":[],"swing_feet":[]}"#;
    assert!(from_json::<TaskReferences>(old).unwrap().foot_loads.is_empty());
}

fn any_kind_decode(bytes: &[u8]) {
    // Each must return (Ok or Err) without panicking.
    let _ = decode::<RobotState>(bytes);
    let _ = decode::<DynamicsTerms>(bytes);
    let _ = decode::<TorqueCommand>(bytes);
    let _ = decode::<DriveCommand>(bytes);
    let _ = decode::<TaskReferences>(bytes);
    let _ = decode::<PerturbationRequest>(bytes);
    let _ = decode::<CoordinatorStatus>(bytes);
    let _ = decode::<TickDiagnostics>(bytes);
    let _ = decode::<AgentStatus>(bytes);
    let _ = decode::<RobotDescription>(bytes);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        any_kind_decode(&bytes);
        prop_assert!(decode::<TorqueCommand>(&bytes).is_err() || bytes.starts_with(b"TQ"));
    }

    #[test]
    fn random_bytes_behind_a_valid_envelope_never_panic(kind in 1u8..10, body in proptest::collection::vec(any::<u8>(), 0..512)) {
        let mut bytes = vec![b'T', b'Q', PROTOCOL_VERSION as u8, 0, kind, 0];
        bytes.extend_from_slice(&body);
        any_kind_decode(&bytes);
    }

    #[test]
    fn flipped_bytes_of_a_valid_message_never_panic(pos in 0usize..4096, val in any::<u8>()) {
        let mut b = encode(&dynamics(8)).unwrap();
        let p = pos % b.len();
        b[p] = val;
        any_kind_decode(&b);
    }

    #[test]
    fn a_bad_number_anywhere_is_caught(idx in 0usize..4096, which in 0usize..3) {
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][which];
        let mut d = dynamics(8);
        let n = d.mass_matrix.data.len();
        d.mass_matrix.data[idx % n] = bad;
        let is_non_finite = matches!(decode::<DynamicsTerms>(&raw(&d)), Err(ProtocolError::NonFinite { .. }));
        prop_assert!(is_non_finite);
    }

    #[test]
    fn random_json_never_panics(s in ".{0,200}") {
        let _ = from_json::<RobotState>(&s);
        let _ = from_json::<TaskReferences>(&s);
    }
}

fn contact_set(feet: &[&str]) -> ContactSet {
    ContactSet {
        header: header(true),
        stance_feet: feet.iter().map(|f| f.to_string()).collect(),
        hand_in_grasp: true,
    }
}

#[test]
fn contact_set_round_trips_and_refuses_duplicates_and_bad_names() {
    let c = contact_set(&["LF_FOOT", "RH_FOOT"]);
    assert_eq!(decode::<ContactSet>(&encode(&c).unwrap()).unwrap(), c);
    assert_eq!(from_json::<ContactSet>(&to_json(&c).unwrap()).unwrap(), c);
    assert_eq!(MessageKind::ContactSet as u8, 10);
    assert_eq!(keys::contacts("team1", "r1").unwrap(), "team/team1/robot/r1/contacts");
    for bad in [contact_set(&["LF_FOOT", "LF_FOOT"]), contact_set(&[""]), contact_set(&["a foot"])]
    {
        let mut bytes = Vec::new();
        encode_into(&bad, &mut bytes).unwrap();
        assert!(
            matches!(decode::<ContactSet>(&bytes), Err(ProtocolError::Invalid { .. })),
            "{bad:?} accepted"
        );
    }
    let mut no_robot = contact_set(&[]);
    no_robot.header.robot = None;
    assert!(encode(&no_robot).is_err());
    // Another kind's bytes are not a contact set.
    assert!(matches!(
        decode::<ContactSet>(&encode(&command(3)).unwrap()),
        Err(ProtocolError::WrongKind { .. })
    ));
}

fn description() -> RobotDescription {
    RobotDescription {
        header: header(true),
        joint_names: vec!["j1".into(), "j2".into()],
        torque_limits: vec![10.0, 20.0],
        floating_base: true,
        nq: 9,
        nv: 8,
        foot_frames: vec!["foot".into()],
        hand_frame: "hand".into(),
        torso_frame: "base".into(),
        foot_mu: 0.8,
        hand_mu: 0.8,
        hand_xi: 0.03,
        hand_half_size: [0.075, 0.05],
        total_mass: 10.0,
    }
}

#[test]
fn contact_parameters_must_be_positive() {
    decode::<RobotDescription>(&raw(&description())).expect("a valid description");
    // xi = 0 too: a hand's friction rows divide by it (coordinator/src/qp/rows.rs).
    let bad: [fn(&mut RobotDescription); 4] = [
        |d| d.foot_mu = 0.0,
        |d| d.hand_mu = -0.1,
        |d| d.hand_xi = 0.0,
        |d| d.hand_half_size[1] = 0.0,
    ];
    for (k, edit) in bad.iter().enumerate() {
        let mut d = description();
        edit(&mut d);
        let e = decode::<RobotDescription>(&raw(&d)).expect_err("refused").to_string();
        assert!(e.contains("contact parameters"), "case {k}: {e}");
    }
}

fn drive(n: usize, gains: bool) -> DriveCommand {
    let mut d = DriveCommand::torque("team1", "r1", 42, (0..n).map(|j| 1.0 + j as f64).collect());
    if gains {
        d.kp = vec![100.0; n];
        d.q_des = (0..n).map(|j| 0.1 * j as f64).collect();
        d.kd = vec![5.0; n];
        d.qd_des = vec![0.2; n];
    }
    d
}

#[test]
fn a_drive_command_round_trips_and_its_law_is_the_pd_law_written_out() {
    for gains in [false, true] {
        let d = drive(6, gains);
        assert_eq!(decode::<DriveCommand>(&encode(&d).unwrap()).unwrap(), d);
    }
    let d = drive(3, true);
    let (q, qd) = ([0.05, -0.1, 0.3], [0.0, 1.0, -0.5]);
    let mut out = [0.0; 3];
    d.effort(0.0, &q, &qd, &mut out);
    for j in 0..3 {
        let written = d.tau_ff[j] + 100.0 * (0.1 * j as f64 - q[j]) + 5.0 * (0.2 - qd[j]);
        assert!((out[j] - written).abs() < 1e-12, "joint {j}: {} against {written}", out[j]);
    }
    drive(3, false).effort(0.0, &q, &qd, &mut out);
    assert_eq!(out, [1.0, 2.0, 3.0], "no gains: the torque as it is");
}

#[test]
fn a_broken_drive_command_is_refused_naming_the_field() {
    let field = |d: &DriveCommand| match d.validate() {
        Err(ProtocolError::Invalid { field, .. }) | Err(ProtocolError::NonFinite { field, .. }) => {
            field
        }
        other => panic!("refused expected, got {other:?}"),
    };
    let mut d = drive(4, true);
    d.kp.pop();
    assert_eq!(field(&d), "kp", "3 gains for 4 joints");
    let mut d = drive(4, true);
    d.qd_des.clear();
    assert_eq!(field(&d), "qd_des", "gains without targets");
    let mut d = drive(4, true);
    d.kd[2] = -1.0;
    assert_eq!(field(&d), "kd", "negative damping");
    let mut d = drive(4, true);
    d.q_des[1] = f64::NAN;
    assert_eq!(field(&d), "q_des");
    let mut d = drive(4, false);
    d.tau_ff[0] = f64::INFINITY;
    assert_eq!(field(&d), "tau_ff");
    assert_eq!(field(&drive(0, false)), "tau_ff", "no joints");
    // Encoded without the checks (`encode_into`), a broken command is still refused where it arrives.
    let mut d = drive(4, true);
    d.kp[0] = -5.0;
    let mut bytes = Vec::new();
    encode_into(&d, &mut bytes).unwrap();
    assert!(decode::<DriveCommand>(&bytes).is_err());
}

#[test]
fn a_drive_command_of_the_first_protocol_version_is_refused() {
    let mut bytes = encode(&drive(3, false)).unwrap();
    bytes[2] = 1; // version 1, little endian
    assert!(
        matches!(
            decode::<DriveCommand>(&bytes),
            Err(ProtocolError::VersionMismatch { found: 1, .. })
        ),
        "{:?}",
        decode::<DriveCommand>(&bytes)
    );
}

#[test]
fn a_drive_trajectory_is_carried_from_its_time_and_held_after_its_end() {
    let mut d = drive(2, true);
    d.ref_time = Some(1.0);
    d.qdd_des = vec![4.0, -2.0];
    d.valid_until = Some(1.01);
    assert!(protocol::Validate::validate(&d).is_ok());
    // Joint 1 at 1.005 s: q = 0.1 + 0.2 s + 0.5 (-2) s^2, qd = 0.2 - 2 s, s = 5 ms.
    let s: f64 = 0.005;
    let (q, qd) = d.targets_at(1, 1.0 + s);
    assert!((q.unwrap() - (0.1 + 0.2 * s - s * s)).abs() < 1e-15);
    assert!((qd.unwrap() - (0.2 - 2.0 * s)).abs() < 1e-15);
    // Before its time the targets are the state's; after its end, the end's position at rest.
    assert_eq!(d.targets_at(0, 0.5), (Some(0.0), Some(0.2)));
    let end: f64 = 0.01;
    let (q, qd) = d.targets_at(0, 2.0);
    assert!((q.unwrap() - (0.2 * end + 2.0 * end * end)).abs() < 1e-15);
    assert_eq!(qd, Some(0.0));
    assert!(!d.expired(1.01) && d.expired(1.0101));
    // The law follows the carried targets: at the trajectory's point it is the torque.
    let (q0, qd0) = d.targets_at(0, 1.0 + s);
    let (q1, qd1) = d.targets_at(1, 1.0 + s);
    let mut out = [0.0; 2];
    d.effort(1.0 + s, &[q0.unwrap(), q1.unwrap()], &[qd0.unwrap(), qd1.unwrap()], &mut out);
    assert!((out[0] - 1.0).abs() < 1e-9 && (out[1] - 2.0).abs() < 1e-9, "{out:?}");
    // Without ref_time the targets are constant, as before.
    assert_eq!(drive(2, true).targets_at(1, 5.0), (Some(0.1), Some(0.2)));
}

#[test]
fn a_drive_trajectory_that_does_not_add_up_is_refused() {
    let base = || {
        let mut d = drive(2, true);
        d.ref_time = Some(1.0);
        d
    };
    type Edit = Box<dyn Fn(&mut DriveCommand)>;
    let cases: [(&str, Edit); 5] = [
        ("qdd_des", Box::new(|d| d.qdd_des = vec![1.0])),
        ("qdd_des", Box::new(|d| d.qdd_des = vec![f64::NAN, 0.0])),
        ("qdd_des", Box::new(|d| (d.ref_time, d.qdd_des) = (None, vec![0.0, 0.0]))),
        ("ref_time", Box::new(|d| d.ref_time = Some(f64::INFINITY))),
        ("valid_until", Box::new(|d| d.valid_until = Some(0.5))),
    ];
    for (field, edit) in cases {
        let mut d = base();
        edit(&mut d);
        let e = protocol::Validate::validate(&d).expect_err(field).to_string();
        assert!(e.contains(field), "{field}: {e}");
        assert!(encode(&d).is_err(), "{field}: not sent");
    }
}
