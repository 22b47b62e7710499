//! Writing a run's report folder: a CSV time series, `metrics.json` and SVG plots like the
//! paper's figures (desired and measured trajectories, torque RMS per joint).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use plotters::prelude::*;
use thiserror::Error;

/// Errors writing a report.
#[derive(Debug, Error)]
pub enum ReportError {
    #[error("cannot write {path}: {reason}")]
    Io { path: String, reason: String },
    #[error("plot {path}: {reason}")]
    Plot { path: String, reason: String },
    #[error("series {name:?} has {got} samples, the time axis has {expected}")]
    Length { name: String, expected: usize, got: usize },
}

/// Named columns over one time axis.
#[derive(Debug, Clone, Default)]
pub struct TimeSeries {
    pub time: Vec<f64>,
    pub columns: Vec<(String, Vec<f64>)>,
}

impl TimeSeries {
    /// A series with the given column names.
    pub fn with_columns(names: &[String]) -> Self {
        TimeSeries { time: Vec::new(), columns: names.iter().map(|n| (n.clone(), Vec::new())).collect() }
    }

    /// Append one row (one value per column, in order).
    pub fn push(&mut self, t: f64, row: &[f64]) {
        self.time.push(t);
        for (c, v) in self.columns.iter_mut().zip(row) {
            c.1.push(*v);
        }
    }

    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.columns.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_slice())
    }

    fn check(&self) -> Result<(), ReportError> {
        for (name, v) in &self.columns {
            if v.len() != self.time.len() {
                return Err(ReportError::Length { name: name.clone(), expected: self.time.len(), got: v.len() });
            }
        }
        Ok(())
    }

    /// Write as CSV with a `t` column first.
    pub fn write_csv(&self, path: &Path) -> Result<(), ReportError> {
        self.check()?;
        let io = |e: std::io::Error| ReportError::Io { path: path.display().to_string(), reason: e.to_string() };
        let mut w = BufWriter::new(File::create(path).map_err(io)?);
        write!(w, "t").map_err(io)?;
        for (n, _) in &self.columns {
            write!(w, ",{n}").map_err(io)?;
        }
        writeln!(w).map_err(io)?;
        for (k, t) in self.time.iter().enumerate() {
            write!(w, "{t}").map_err(io)?;
            for (_, v) in &self.columns {
                write!(w, ",{}", v[k]).map_err(io)?;
            }
            writeln!(w).map_err(io)?;
        }
        w.flush().map_err(io)
    }
}

const COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// One panel of a [`plot_panels`] figure: pairs of (desired, measured) columns drawn in the
/// same colour, desired dashed-looking (thin) and measured thick.
pub struct Panel<'a> {
    pub title: &'a str,
    pub y_label: &'a str,
    /// `(legend, desired column, measured column)`.
    pub pairs: Vec<(&'a str, &'a str, &'a str)>,
}

/// Stacked panels of desired-versus-measured trajectories over time, as an SVG file.
pub fn plot_panels(series: &TimeSeries, panels: &[Panel], path: &Path) -> Result<(), ReportError> {
    series.check()?;
    let perr = |e: String| ReportError::Plot { path: path.display().to_string(), reason: e };
    let root = SVGBackend::new(path, (900, 260 * panels.len() as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
    let areas = root.split_evenly((panels.len(), 1));
    let (t0, t1) = (series.time.first().copied().unwrap_or(0.0), series.time.last().copied().unwrap_or(1.0));
    for (panel, area) in panels.iter().zip(areas.iter()) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for (_, d, m) in &panel.pairs {
            for name in [d, m] {
                let col = series.column(name).ok_or_else(|| perr(format!("no column {name}")))?;
                for v in col.iter().filter(|v| v.is_finite()) {
                    lo = lo.min(*v);
                    hi = hi.max(*v);
                }
            }
        }
        if !lo.is_finite() {
            (lo, hi) = (-1.0, 1.0);
        }
        let pad = ((hi - lo) * 0.1).max(1e-6);
        let mut chart = ChartBuilder::on(area)
            .caption(panel.title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(60)
            .build_cartesian_2d(t0..t1.max(t0 + 1e-9), (lo - pad)..(hi + pad))
            .map_err(|e| perr(e.to_string()))?;
        chart.configure_mesh().x_desc("t [s]").y_desc(panel.y_label).draw().map_err(|e| perr(e.to_string()))?;
        for (i, (legend, d, m)) in panel.pairs.iter().enumerate() {
            let color = COLORS[i % COLORS.len()];
            let dcol = series.column(d).expect("checked above");
            let mcol = series.column(m).expect("checked above");
            chart
                .draw_series(LineSeries::new(series.time.iter().copied().zip(dcol.iter().copied()), color.stroke_width(1)))
                .map_err(|e| perr(e.to_string()))?
                .label(format!("{legend} des"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(1)));
            chart
                .draw_series(LineSeries::new(series.time.iter().copied().zip(mcol.iter().copied()), color.mix(0.6).stroke_width(3)))
                .map_err(|e| perr(e.to_string()))?
                .label(format!("{legend} mrt"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.mix(0.6).stroke_width(3)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| perr(e.to_string()))?;
    }
    root.present().map_err(|e| perr(e.to_string()))
}

/// A bar chart of values per label (e.g. torque RMS per joint), as an SVG file.
pub fn plot_bars(title: &str, y_label: &str, labels: &[String], values: &[f64], path: &Path) -> Result<(), ReportError> {
    let perr = |e: String| ReportError::Plot { path: path.display().to_string(), reason: e };
    if labels.len() != values.len() {
        return Err(ReportError::Length { name: title.to_string(), expected: labels.len(), got: values.len() });
    }
    let root = SVGBackend::new(path, (900, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
    let top = values.iter().copied().filter(|v| v.is_finite()).fold(0.0, f64::max).max(1e-9) * 1.1;
    let n = labels.len().max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(80)
        .y_label_area_size(60)
        .build_cartesian_2d((0..n).into_segmented(), 0.0..top)
        .map_err(|e| perr(e.to_string()))?;
    let names = labels.to_vec();
    chart
        .configure_mesh()
        .y_desc(y_label)
        .x_labels(n)
        .x_label_formatter(&|x| match x {
            SegmentValue::CenterOf(i) => names.get(*i).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .x_label_style(("sans-serif", 11).into_font().transform(FontTransform::Rotate90))
        .draw()
        .map_err(|e| perr(e.to_string()))?;
    chart
        .draw_series(values.iter().enumerate().map(|(i, v)| {
            let mut bar = Rectangle::new([(SegmentValue::Exact(i), 0.0), (SegmentValue::Exact(i + 1), *v)], COLORS[0].filled());
            bar.set_margin(0, 0, 3, 3);
            bar
        }))
        .map_err(|e| perr(e.to_string()))?;
    root.present().map_err(|e| perr(e.to_string()))
}

/// Write any serialisable value as pretty JSON.
pub fn write_json<T: serde::Serialize>(value: &T, path: &Path) -> Result<(), ReportError> {
    let io = |e: String| ReportError::Io { path: path.display().to_string(), reason: e };
    let text = serde_json::to_string_pretty(value).map_err(|e| io(e.to_string()))?;
    std::fs::write(path, text + "\n").map_err(|e| io(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_and_plots_are_written() {
        let dir = std::env::temp_dir().join(format!("report-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let names: Vec<String> = ["x_des", "x_mrt"].iter().map(|s| s.to_string()).collect();
        let mut ts = TimeSeries::with_columns(&names);
        for k in 0..100 {
            let t = k as f64 * 0.01;
            ts.push(t, &[t.sin(), t.sin() + 0.01]);
        }
        ts.write_csv(&dir.join("ts.csv")).unwrap();
        let csv = std::fs::read_to_string(dir.join("ts.csv")).unwrap();
        assert_eq!(csv.lines().count(), 101);
        assert!(csv.starts_with("t,x_des,x_mrt\n0,0,0.01\n"));
        plot_panels(&ts, &[Panel { title: "object x", y_label: "m", pairs: vec![("x", "x_des", "x_mrt")] }], &dir.join("p.svg")).unwrap();
        let svg = std::fs::read_to_string(dir.join("p.svg")).unwrap();
        assert!(svg.contains("<svg") && svg.contains("object x") && svg.contains("polyline"));
        plot_bars("torque RMS", "N m", &["a".into(), "b".into()], &[1.0, 2.0], &dir.join("b.svg")).unwrap();
        assert!(std::fs::read_to_string(dir.join("b.svg")).unwrap().contains("<rect"));
        // A missing column is an error, not a panic.
        let bad = Panel { title: "y", y_label: "m", pairs: vec![("y", "y_des", "y_mrt")] };
        assert!(plot_panels(&ts, &[bad], &dir.join("bad.svg")).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
