//! The figures of a walk: the gait diagram (each foot's measured contact against its planned
//! stance), foot heights against the swing references with the swing error, and the torsos'
//! (and a carried object's) paths seen from above.

use nalgebra::Vector3;

use super::draw::{Line, Panel, Stroke, GREY, PALETTE, RED};
use crate::records::Records;
use planner::walk::Walk;

/// The walk's figures: (file stem, caption), after the report's own.
pub const FIGURES: [(&str, &str); 3] = [
    (
        "gait",
        "Gait diagram: measured foot contact (solid) and planned stance (dashed), one row per foot",
    ),
    (
        "foot_heights",
        "Foot heights: measured (solid) and swing references (dashed), and the swing error",
    ),
    ("torso_paths", "Torso and object paths from above: desired (dashed) and measured (solid)"),
];

/// A path drawn as it goes (every `n`-th point, not decimated along x).
fn path(
    label: String,
    pts: Vec<(f64, f64)>,
    color: plotters::style::RGBColor,
    stroke: Stroke,
) -> Line {
    let every = (pts.len() / 600).max(1);
    let mut line = Line::new(label, Vec::new(), color, stroke);
    line.points = pts.into_iter().step_by(every).collect();
    line
}

/// One row per foot of each walking robot: measured contact at `k + 0.8`, planned stance at
/// `k + 0.5` (dashed), swing at `k`.
pub fn gait_diagram(walk: &Walk, records: &Records) -> Vec<Panel> {
    let mut panels = Vec::new();
    for (i, id) in walk.robots.iter().enumerate().filter(|(i, _)| walk.walking[*i]) {
        let mut lines = Vec::new();
        for (k, (frame, link)) in walk.feet[i].iter().zip(&walk.foot_links[i]).enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let y = k as f64;
            let measured = records
                .truth
                .iter()
                .map(|g| {
                    (
                        g.time,
                        y + if g.foot_contacts.iter().any(|x| &x.robot == id && &x.body == link) {
                            0.8
                        } else {
                            0.0
                        },
                    )
                })
                .collect();
            let planned = records
                .truth
                .iter()
                .map(|g| (g.time, y + if walk.gait.stance(i, g.time)[k] { 0.5 } else { 0.0 }))
                .collect();
            lines.push(path(format!("{frame} contact"), measured, c, Stroke::Solid));
            lines.push(path(format!("{frame} planned"), planned, GREY, Stroke::Dashed));
        }
        panels.push(Panel { title: format!("{id} gait"), y_label: "foot".into(), lines });
    }
    panels
}

/// Each walking robot's foot heights (mm above the start) against the swing references, and
/// the swing feet's position error (mm) while a reference is given.
pub fn foot_heights(walk: &Walk, records: &Records) -> Vec<Panel> {
    let mut panels = Vec::new();
    for (i, id) in walk.robots.iter().enumerate().filter(|(i, _)| walk.walking[*i]) {
        let (mut heights, mut errors) = (Vec::new(), Vec::new());
        for (k, frame) in walk.feet[i].iter().enumerate() {
            let name = format!("{id}/{frame}");
            let c = PALETTE[k % PALETTE.len()];
            let at = |g: &protocol::GroundTruth| {
                g.feet.iter().find(|b| b.name == name).map(|b| Vector3::from(b.pose.position))
            };
            let z0 = records.truth.iter().find_map(at).map_or(0.0, |p| p.z);
            let measured = records
                .truth
                .iter()
                .filter_map(|g| at(g).map(|p| (g.time, 1e3 * (p.z - z0))))
                .collect();
            let swing: Vec<(f64, Vector3<f64>, Vector3<f64>)> = records
                .truth
                .iter()
                .filter(|g| !walk.gait.stance(i, g.time)[k])
                .filter_map(|g| Some((g.time, at(g)?, walk.gait.swing_foot(i, k, g.time)?.0)))
                .collect();
            heights.push(path(frame.to_string(), measured, c, Stroke::Solid));
            heights.push(path(
                format!("{frame} ref"),
                swing.iter().map(|(t, _, r)| (*t, 1e3 * (r.z - z0))).collect(),
                GREY,
                Stroke::Dashed,
            ));
            errors.push(path(
                frame.to_string(),
                swing.iter().map(|(t, p, r)| (*t, 1e3 * (p - r).norm())).collect(),
                c,
                Stroke::Solid,
            ));
        }
        panels.push(Panel {
            title: format!("{id} foot heights"),
            y_label: "mm".into(),
            lines: heights,
        });
        panels.push(Panel {
            title: format!("{id} swing foot error |p - p_ref|"),
            y_label: "mm".into(),
            lines: errors,
        });
    }
    panels
}

/// Torso paths (and the object's, when the team carries it) in the x-y plane.
pub fn torso_paths(
    walk: &Walk,
    records: &Records,
    desired_torso: impl Fn(usize, f64) -> [f64; 3],
    desired_object: impl Fn(f64) -> [f64; 3],
) -> Vec<Panel> {
    let mut lines = Vec::new();
    for (i, id) in walk.robots.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let measured = records
            .truth
            .iter()
            .filter_map(|g| {
                g.torsos
                    .iter()
                    .find(|b| &b.name == id)
                    .map(|b| (b.pose.position[0], b.pose.position[1]))
            })
            .collect();
        let desired =
            records.truth.iter().map(|g| desired_torso(i, g.time)).map(|p| (p[0], p[1])).collect();
        lines.push(path(id.to_string(), measured, c, Stroke::Solid));
        lines.push(path(format!("{id} desired"), desired, GREY, Stroke::Dashed));
    }
    if walk.moves_object {
        let measured = records
            .truth
            .iter()
            .filter_map(|g| g.object.as_ref().map(|b| (b.pose.position[0], b.pose.position[1])))
            .collect();
        lines.push(path("object".into(), measured, RED, Stroke::Solid));
        lines.push(path(
            "object desired".into(),
            records.truth.iter().map(|g| desired_object(g.time)).map(|p| (p[0], p[1])).collect(),
            GREY,
            Stroke::Dashed,
        ));
    }
    vec![Panel { title: "paths from above".into(), y_label: "y [m]".into(), lines }]
}
