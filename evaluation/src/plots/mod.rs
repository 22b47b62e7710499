//! The figures of a report and its index page, `report.html`:
//!
//! * `object_error`: the object's tracking error against time per axis (mm, deg): measured
//!   minus desired, the thing the bounds are about;
//! * `object`: desired (dashed, grey) and measured (solid, blue) per axis;
//! * `torso_error`: each torso's position error per axis (mm);
//! * `contact_forces`: each hand's normal and tangential force against its friction limit
//!   `mu f_n`, and each robot's feet friction use `|f_t| / (mu f_n)` (at most 1 in the cone);
//! * `qp_timing`: the QP solve time and the whole controller tick per tick (us);
//! * `torque_rms`: the commanded torque RMS per joint, joint names readable;
//! * `loop_timing` (real-time runs only, [`LOOP_FIGURE`]): state-to-torque latency per robot
//!   against the control period, and the ticks each robot's drive held its last torques.
//!
//! A walking scenario adds [`walk::FIGURES`]: the gait diagram, foot heights and the paths
//! from above.
//!
//! Each as PNG and SVG (see [`draw`]). Inputs: the plan, the evaluation and the driver's
//! records, so a replayed recording draws the same figures.

pub mod draw;
pub mod walk;

use std::path::Path;

use nalgebra::Vector3;

use crate::evaluate::{self, Evaluation};
use crate::records::Records;
use crate::report::{ReportError, TimeSeries};
use draw::{Line, Panel, Stroke, BLUE, GREEN, GREY, ORANGE, RED};
use scenario::plan::Plan;

/// The figures, in the order the index page shows them: (file stem, caption).
pub const FIGURES: [(&str, &str); 6] = [
    ("object_error", "Object tracking error per axis (measured minus desired)"),
    ("object", "Object pose: desired (dashed) and measured (solid)"),
    ("torso_error", "Torso position error per axis"),
    ("contact_forces", "Contact forces against the friction limits"),
    ("qp_timing", "QP solve time and controller tick time"),
    ("torque_rms", "Commanded torque RMS per joint"),
];

const AXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];

/// Draw every figure and write `report.html` in `dir`.
pub fn write_all(
    plan: &Plan,
    eval: &Evaluation,
    records: &Records,
    dir: &Path,
) -> Result<(), ReportError> {
    let s = &eval.series;
    draw::panels(dir, "object_error", "object tracking error", &object_error(s), 3, "t [s]")?;
    draw::panels(dir, "object", "object pose", &object_overlay(s), 3, "t [s]")?;
    draw::panels(dir, "torso_error", "torso position error", &torso_error(plan, s), 3, "t [s]")?;
    draw::panels(
        dir,
        "contact_forces",
        "contact forces",
        &contact_forces(plan, records),
        2,
        "t [s]",
    )?;
    draw::panels(dir, "qp_timing", "coordinator timing", &qp_timing(plan, records), 1, "t [s]")?;
    draw_torque_rms(eval, dir)?;
    let mut figures: Vec<(&str, &str)> = FIGURES.to_vec();
    if eval.metrics.loop_timing.is_some() {
        draw::panels(
            dir,
            "loop_timing",
            "control loop (real time)",
            &loop_timing(plan, records),
            1,
            "t [s]",
        )?;
        figures.push(LOOP_FIGURE);
    }
    if let Some(w) = &plan.references.walk {
        draw_walk(plan, w, records, dir)?;
        figures.extend(walk::FIGURES);
    }
    write_index(eval, dir, &figures)
}

/// The bar chart of the commanded torque RMS of every joint, robot by robot.
fn draw_torque_rms(eval: &Evaluation, dir: &Path) -> Result<(), ReportError> {
    let (mut labels, mut values) = (Vec::new(), Vec::new());
    for (r, joints) in &eval.metrics.torque_rms {
        for (j, v) in joints {
            labels.push(format!("{r} {j}"));
            values.push(*v);
        }
    }
    draw::bars(dir, "torque_rms", "commanded torque RMS per joint", "N m", &labels, &values)
}

/// The walk's figures: gait diagram, foot heights and the paths seen from above.
fn draw_walk(
    plan: &Plan,
    w: &planner::walk::Walk,
    records: &Records,
    dir: &Path,
) -> Result<(), ReportError> {
    let refs = &plan.references;
    draw::panels(dir, "gait", "gait diagram", &walk::gait_diagram(w, records), 1, "t [s]")?;
    draw::panels(dir, "foot_heights", "foot heights", &walk::foot_heights(w, records), 2, "t [s]")?;
    let torso = |i: usize, t: f64| refs.torso_at(i, Some(t)).pose.position;
    let object = |t: f64| refs.object_at(Some(t)).pose.position;
    draw::panels(
        dir,
        "torso_paths",
        "paths from above",
        &walk::torso_paths(w, records, torso, object),
        1,
        "x [m]",
    )
}

fn column<'a>(s: &'a TimeSeries, name: &str) -> &'a [f64] {
    s.column(name).unwrap_or(&[])
}

/// `(t, scale * (measured - desired))` of a `{prefix}_des` / `{prefix}_mrt` column pair.
fn error_points(s: &TimeSeries, prefix: &str, scale: f64) -> Vec<(f64, f64)> {
    let (d, m) = (column(s, &format!("{prefix}_des")), column(s, &format!("{prefix}_mrt")));
    s.time.iter().zip(d.iter().zip(m)).map(|(t, (d, m))| (*t, scale * (m - d))).collect()
}

fn unit_of(axis: &str) -> (&'static str, f64) {
    if axis.starts_with('r') {
        ("deg", 180.0 / std::f64::consts::PI)
    } else {
        ("mm", 1e3)
    }
}

fn object_error(s: &TimeSeries) -> Vec<Panel> {
    AXES.iter()
        .map(|a| {
            let (unit, scale) = unit_of(a);
            let line = Line::new(
                format!("{a} error"),
                error_points(s, &format!("object_{a}"), scale),
                RED,
                Stroke::Solid,
            );
            Panel { title: format!("object {a} error"), y_label: unit.into(), lines: vec![line] }
        })
        .collect()
}

fn object_overlay(s: &TimeSeries) -> Vec<Panel> {
    AXES.iter()
        .map(|a| {
            let (unit, scale) =
                if a.starts_with('r') { ("deg", 180.0 / std::f64::consts::PI) } else { ("m", 1.0) };
            let pts = |suffix: &str| {
                s.time
                    .iter()
                    .zip(column(s, &format!("object_{a}_{suffix}")))
                    .map(|(t, v)| (*t, scale * v))
                    .collect()
            };
            Panel {
                title: format!("object {a}"),
                y_label: unit.into(),
                lines: vec![
                    Line::new("measured", pts("mrt"), BLUE, Stroke::Solid),
                    Line::new("desired", pts("des"), GREY, Stroke::Dashed),
                ],
            }
        })
        .collect()
}

fn torso_error(plan: &Plan, s: &TimeSeries) -> Vec<Panel> {
    let mut panels = Vec::new();
    for r in &plan.robots {
        for a in ["x", "y", "z"] {
            let line = Line::new(
                format!("{a} error"),
                error_points(s, &format!("{}_torso_{a}", r.id), 1e3),
                RED,
                Stroke::Solid,
            );
            panels.push(Panel {
                title: format!("torso {} {a} error", r.id),
                y_label: "mm".into(),
                lines: vec![line],
            });
        }
    }
    panels
}

/// Per robot: the hand's normal force, tangential force and friction limit (N), and the feet's
/// largest friction use.
fn contact_forces(plan: &Plan, records: &Records) -> Vec<Panel> {
    let mut panels = Vec::new();
    for r in &plan.robots {
        let (hand_mu, foot_mu) = (r.robot.hand.mu, r.robot.feet.mu);
        let (mut fn_, mut ft, mut limit, mut feet) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for g in &records.truth {
            let t = g.time;
            let palm = g.hands.iter().find(|b| b.name == r.id);
            let n = palm
                .map(|p| protocol::conventions::quat_from_wxyz(p.pose.orientation) * Vector3::z())
                .unwrap_or_else(Vector3::z);
            let f: Vector3<f64> = g
                .hand_contacts
                .iter()
                .filter(|c| c.robot == r.id)
                .map(|c| Vector3::new(c.wrench[0], c.wrench[1], c.wrench[2]))
                .sum();
            let normal = n.dot(&f);
            fn_.push((t, normal));
            ft.push((t, (f - n * normal).norm()));
            limit.push((t, hand_mu * normal.max(0.0)));
            let usage = g
                .foot_contacts
                .iter()
                .filter(|c| c.robot == r.id && c.wrench[2] > 1e-6)
                .map(|c| c.wrench[0].hypot(c.wrench[1]) / (foot_mu * c.wrench[2]))
                .fold(0.0, f64::max);
            feet.push((t, usage));
        }
        panels.push(Panel {
            title: format!("{} hand on the object", r.id),
            y_label: "N".into(),
            lines: vec![
                Line::new("normal f_n", fn_, BLUE, Stroke::Solid),
                Line::new("tangential |f_t|", ft, ORANGE, Stroke::Solid),
                Line::new(format!("limit {hand_mu} f_n"), limit, RED, Stroke::Dashed),
            ],
        });
        let one = feet.iter().map(|(t, _)| (*t, 1.0)).collect();
        panels.push(Panel {
            title: format!("{} feet: largest |f_t| / (mu f_n)", r.id),
            y_label: "friction use".into(),
            lines: vec![
                Line::new("largest foot", feet, GREEN, Stroke::Solid),
                Line::new("cone edge", one, RED, Stroke::Dashed),
            ],
        });
    }
    panels
}

fn qp_timing(plan: &Plan, records: &Records) -> Vec<Panel> {
    let t = |tick: u64| plan.references.time_of_tick(tick).unwrap_or(0.0);
    let d = &records.diagnostics;
    vec![
        Panel {
            title: "QP solve time".into(),
            y_label: "us".into(),
            lines: vec![Line::new(
                "solve",
                d.iter().map(|x| (t(x.header.tick), x.qp_solve_us)).collect(),
                BLUE,
                Stroke::Solid,
            )],
        },
        Panel {
            title: "controller tick (assembly, QP, torques)".into(),
            y_label: "us".into(),
            lines: vec![Line::new(
                "tick",
                d.iter().map(|x| (t(x.header.tick), x.total_us)).collect(),
                ORANGE,
                Stroke::Solid,
            )],
        },
    ]
}

/// A real-time run's figure: [`loop_timing`].
pub const LOOP_FIGURE: (&str, &str) = (
    "loop_timing",
    "State-to-torque latency per robot against the control period; \
     the ticks each robot's drive held its last torques",
);

/// Per robot, the state-to-torque latency of each tick whose torques came in time, with the
/// control period (the deadline) dashed; below, each robot's deadline misses counted up over
/// the run (a step is a tick its drive held its last torques).
fn loop_timing(plan: &Plan, records: &Records) -> Vec<Panel> {
    let t = |tick: u64| plan.references.time_of_tick(tick).unwrap_or(0.0);
    let period_us = plan.references.clock.dt_us();
    let robots: Vec<&str> = plan.robots.iter().map(|r| r.id.as_str()).collect();
    let mut latency = Vec::new();
    let mut missed = Vec::new();
    for (i, r) in robots.iter().enumerate() {
        let color = draw::PALETTE[i % draw::PALETTE.len()];
        let timings = records.truth.iter().flat_map(|g| {
            g.loop_timing.iter().filter(|l| l.robot == *r).map(move |l| (g.header.tick, l))
        });
        let (mut on_time, mut held, mut count) = (Vec::new(), Vec::new(), 0u64);
        for (tick, l) in timings {
            match l.latency_us {
                Some(us) => on_time.push((t(tick), us)),
                None => count += 1,
            }
            held.push((t(tick), count as f64));
        }
        latency.push(Line::new(*r, on_time, color, Stroke::Solid));
        missed.push(Line::new(format!("{r} ({count} missed)"), held, color, Stroke::Solid));
    }
    let span = |g: &protocol::GroundTruth| t(g.header.tick);
    let (t0, t1) = records
        .truth
        .iter()
        .filter(|g| !g.loop_timing.is_empty())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), g| (a.min(span(g)), b.max(span(g))));
    if t0 <= t1 {
        latency.push(Line::new(
            "control period",
            vec![(t0, period_us), (t1, period_us)],
            GREY,
            Stroke::Dashed,
        ));
    }
    vec![
        Panel {
            title: "state-to-torque latency (ticks in time)".into(),
            y_label: "us".into(),
            lines: latency,
        },
        Panel {
            title: "deadline misses so far (the drive held its last torques)".into(),
            y_label: "ticks".into(),
            lines: missed,
        },
    ]
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// `report.html`: the summary, the checks and every figure (PNG, linked to its SVG).
pub fn write_index(
    eval: &Evaluation,
    dir: &Path,
    figures: &[(&str, &str)],
) -> Result<(), ReportError> {
    let m = &eval.metrics;
    let mut h = String::new();
    h.push_str(&format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{0}</title>\n",
        escape(&m.scenario)
    ));
    h.push_str(
        "<style>body{font-family:sans-serif;max-width:1700px;margin:auto}\
         img{max-width:100%;border:1px solid #ddd}td,th{padding:2px 8px}.fail{color:#c00}\
         </style></head><body>\n",
    );
    h.push_str(&format!("<h1>{}</h1>\n", escape(&m.scenario)));
    if let Some(e) = &m.error {
        h.push_str(&format!(
            "<p class=\"fail\"><b>The run ended in an error</b> after {} of {} ticks: {}. \
             This report is of the ticks it saw.</p>\n",
            m.ticks_seen,
            m.ticks_planned,
            escape(e)
        ));
    }
    h.push_str(&format!("<pre>{}</pre>\n", escape(&evaluate::summary(m, dir))));
    h.push_str(
        "<h2>Acceptance checks</h2>\n\
         <table><tr><th>check</th><th>value</th><th>bound</th><th></th></tr>\n",
    );
    for c in &m.checks {
        let (class, mark) = if c.passed { ("", "passed") } else { (" class=\"fail\"", "FAILED") };
        h.push_str(&format!(
            "<tr{class}><td>{}</td><td>{:.5}</td><td>{}</td><td>{mark}</td></tr>\n",
            escape(&c.name),
            c.value,
            c.bound
        ));
    }
    h.push_str(
        "</table>\n<p>Files: <a href=\"metrics.json\">metrics.json</a>, \
         <a href=\"timeseries.csv\">timeseries.csv</a>, <a href=\"torques.csv\">torques.csv</a>, \
         <a href=\"run.mcap\">run.mcap</a> (open in Foxglove; \
         <code>team report run.mcap</code> rebuilds this page).</p>\n",
    );
    for (stem, caption) in figures {
        h.push_str(&format!(
            "<h2>{caption}</h2>\n\
             <a href=\"{stem}.svg\"><img src=\"{stem}.png\" alt=\"{caption}\"></a>\n"
        ));
    }
    h.push_str("</body></html>\n");
    let path = dir.join("report.html");
    std::fs::write(&path, h)
        .map_err(|e| ReportError::Io { path: path.display().to_string(), reason: e.to_string() })
}
