//! The paper's Fig. controller_comparison (c): the object's Z, desired and under each
//! controller, one panel (kept apart from [`crate::compare`] so that plotting can move), and
//! each controller's Z error below it. Drawn with [`evaluation::plots::draw`] (PNG and SVG).

use std::path::Path;

use evaluation::plots::draw::{self, Line, Panel, Stroke, GREY, PALETTE};
use evaluation::report::{ReportError, TimeSeries};

/// `runs`: (controller, its run's time series, `None` if the run failed) of one scenario.
/// Writes `path` (SVG) and the same stem as PNG: the desired Z (grey, dashed) and each
/// controller's measured Z (solid), then each controller's error (mm).
pub fn object_z(
    runs: &[(String, Option<TimeSeries>)],
    title: &str,
    path: &Path,
) -> Result<(), ReportError> {
    let done: Vec<(&String, &TimeSeries)> =
        runs.iter().filter_map(|(c, s)| s.as_ref().map(|s| (c, s))).collect();
    let Some((_, first)) = done.first() else { return Ok(()) };
    let points = |s: &TimeSeries, col: &str, scale: f64| -> Vec<(f64, f64)> {
        s.time.iter().zip(s.column(col).unwrap_or(&[])).map(|(t, v)| (*t, scale * v)).collect()
    };
    let mut z =
        vec![Line::new("desired", points(first, "object_z_des", 1.0), GREY, Stroke::Dashed)];
    let mut err = Vec::new();
    for (i, (c, s)) in done.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        z.push(Line::new(c.as_str(), points(s, "object_z_mrt", 1.0), color, Stroke::Solid));
        let e = s
            .time
            .iter()
            .zip(
                s.column("object_z_des")
                    .unwrap_or(&[])
                    .iter()
                    .zip(s.column("object_z_mrt").unwrap_or(&[])),
            )
            .map(|(t, (d, m))| (*t, 1e3 * (m - d)))
            .collect();
        err.push(Line::new(c.as_str(), e, color, Stroke::Solid));
    }
    let panels = [
        Panel {
            title: format!("{title}: object Z, desired and per controller"),
            y_label: "m".into(),
            lines: z,
        },
        Panel {
            title: format!("{title}: object Z error per controller"),
            y_label: "mm".into(),
            lines: err,
        },
    ];
    let dir = path.parent().unwrap_or_else(|| Path::new("."));
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "object_z".into());
    draw::panels(dir, &stem, title, &panels, 1, "t [s]")
}
