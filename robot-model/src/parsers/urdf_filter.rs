//! The parts of a URDF that do not change the dynamics, taken out before it is read.
//!
//! ROS tools (robot_state_publisher, RViz) and Pinocchio accept URDFs whose `<visual>` holds two
//! or more `<material>` children, and ignore `<gazebo>` and `<transmission>` blocks and tags they
//! do not know. The rigid-body model reads links' inertials, joints and the tree only, so
//! [`dynamics_only`] drops what cannot change them: every `<visual>` (geometry and materials for
//! display), every `<gazebo>` and `<transmission>`, and every top-level `<material>`. Anything
//! that would change the dynamics is left for the parser to accept or refuse with its reason
//! (joint types it does not model, closed chains, a malformed inertial).

use quick_xml::events::Event;
use quick_xml::{Reader, Writer};

use crate::error::ModelError;

/// Elements left out, wherever they are: display and simulator plug-ins.
const DROPPED: [&[u8]; 3] = [b"visual", b"gazebo", b"transmission"];

/// `urdf` without the elements the dynamics never read (see the module documentation). A URDF
/// that is not well-formed XML is refused with the reader's reason and position.
pub fn dynamics_only(urdf: &str) -> Result<String, ModelError> {
    let mut reader = Reader::from_str(urdf);
    let mut writer = Writer::new(Vec::with_capacity(urdf.len()));
    // Depth inside the element being dropped (0: keeping), and depth below `<robot>`.
    let (mut skipping, mut depth) = (0usize, 0usize);
    loop {
        let event = reader.read_event().map_err(|e| {
            ModelError::Urdf(format!(
                "not well-formed XML at byte {}: {e}",
                reader.error_position()
            ))
        })?;
        let drop = match &event {
            Event::Eof => break,
            Event::Start(e) => {
                depth += 1;
                if skipping > 0 || dropped(e.name().as_ref(), depth) {
                    skipping += 1;
                }
                skipping > 0
            }
            Event::End(_) => {
                depth = depth.saturating_sub(1);
                let inside = skipping > 0;
                skipping = skipping.saturating_sub(1);
                inside
            }
            Event::Empty(e) => skipping > 0 || dropped(e.name().as_ref(), depth + 1),
            _ => skipping > 0,
        };
        if !drop {
            writer
                .write_event(event)
                .map_err(|e| ModelError::Urdf(format!("rewriting the URDF: {e}")))?;
        }
    }
    String::from_utf8(writer.into_inner())
        .map_err(|e| ModelError::Urdf(format!("rewriting the URDF: {e}")))
}

/// Whether an element named `name` at `depth` (1: `<robot>`) is left out: the [`DROPPED`]
/// anywhere, and materials defined at the robot's top level (display only).
fn dropped(name: &[u8], depth: usize) -> bool {
    DROPPED.contains(&name) || (name == b"material" && depth == 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_and_plugins_go_and_the_dynamics_stay() {
        let urdf = r#"<?xml version="1.0"?>
<robot name="r">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  <link name="base">
    <visual><geometry><box size="1 1 1"/></geometry><material name="a"/><material name="b"/></visual>
    <visual/>
    <inertial><mass value="2"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
    <collision><geometry><sphere radius="0.1"/></geometry></collision>
  </link>
  <gazebo reference="base"><material>Gazebo/Grey</material><mu1>0.6</mu1></gazebo>
  <transmission name="t"><type>x</type><joint name="j"/></transmission>
</robot>"#;
        let out = dynamics_only(urdf).unwrap();
        for gone in ["visual", "gazebo", "transmission", "material", "color"] {
            assert!(!out.contains(gone), "{gone} left in {out}");
        }
        for kept in ["<inertial>", "<mass value=\"2\"/>", "<collision>", "<sphere radius"] {
            assert!(out.contains(kept), "{kept} missing from {out}");
        }
    }

    #[test]
    fn malformed_xml_is_refused_with_its_position() {
        let e = dynamics_only("<robot><link name='a'></robot>").unwrap_err().to_string();
        assert!(e.contains("not well-formed XML at byte"), "{e}");
    }
}
