//! The paper's Fig. controller_comparison (c): the object's Z, desired and under each
//! controller, one panel (kept apart from [`crate::compare`] so that plotting can move).

use std::path::Path;

use crate::report::{self, Panel, ReportError, TimeSeries};

/// `runs`: (controller, its run's time series, `None` if the run failed) of one scenario.
/// Writes one panel with each controller's measured object Z against the desired one.
pub fn object_z(runs: &[(String, Option<TimeSeries>)], title: &str, path: &Path) -> Result<(), ReportError> {
    let done: Vec<(&String, &TimeSeries)> = runs.iter().filter_map(|(c, s)| s.as_ref().map(|s| (c, s))).collect();
    let Some((_, first)) = done.first() else { return Ok(()) };
    // Columns: the desired Z (from the first run) and each controller's measured Z, on the
    // first run's sample times (the runs share the scenario's clock; a shorter run is cut).
    let len = done.iter().map(|(_, s)| s.time.len()).min().unwrap_or(0);
    let mut names = vec!["object_z_des".to_string()];
    names.extend(done.iter().map(|(c, _)| format!("{c}_object_z")));
    let mut series = TimeSeries::with_columns(&names);
    let des = first.column("object_z_des").unwrap_or(&[]);
    let measured: Vec<&[f64]> = done.iter().map(|(_, s)| s.column("object_z_mrt").unwrap_or(&[])).collect();
    for (k, (t, d)) in first.time.iter().zip(des).take(len).enumerate() {
        let mut row = vec![*d];
        row.extend(measured.iter().map(|m| m.get(k).copied().unwrap_or(f64::NAN)));
        series.push(*t, &row);
    }
    let legends: Vec<String> = done.iter().map(|(c, _)| c.to_string()).collect();
    let pairs = legends.iter().zip(&names[1..]).map(|(l, m)| (l.as_str(), "object_z_des", m.as_str())).collect();
    let caption = format!("{title}: object Z, desired and per controller");
    report::plot_panels(&series, &[Panel { title: &caption, y_label: "m", pairs }], path)
}
