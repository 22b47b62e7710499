//! Drawing with `plotters`: stacked panels of lines and horizontal bar charts, each written as
//! PNG (bitmap backend, encoded by `png`) and SVG. Text is drawn with the font embedded in the
//! binary ([`FONT`], DejaVu Sans, a subset; no system fonts needed). Lines are decimated for
//! drawing ([`decimate`]: the min and max of each pixel column, so spikes stay visible).

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::report::ReportError;

/// The font of every plot: DejaVu Sans (Bitstream Vera licence and public domain, see
/// `evaluation/assets/LICENSE-DejaVu.txt`), subset to Latin-1 and a few symbols.
pub static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans-subset.ttf");

/// Samples kept per line for drawing: two (min and max) per bucket, about one per pixel
/// column of a panel's plotting area (560 px panels).
pub const BUCKETS: usize = 300;

static REGISTER: Once = Once::new();

/// Register [`FONT`] as plotters' `sans-serif` (once per process).
pub fn register_font() {
    REGISTER.call_once(|| {
        for style in [FontStyle::Normal, FontStyle::Bold] {
            if plotters::style::register_font("sans-serif", style, FONT).is_err() {
                tracing::warn!("the embedded plot font does not load: plots will have no text");
            }
        }
    });
}

/// Colours (Okabe-Ito, readable by colour-blind people).
pub const BLUE: RGBColor = RGBColor(0, 114, 178);
pub const ORANGE: RGBColor = RGBColor(230, 159, 0);
pub const GREEN: RGBColor = RGBColor(0, 158, 115);
pub const RED: RGBColor = RGBColor(213, 94, 0);
pub const PURPLE: RGBColor = RGBColor(204, 121, 167);
pub const GREY: RGBColor = RGBColor(80, 80, 80);
pub const PALETTE: [RGBColor; 5] = [BLUE, ORANGE, GREEN, PURPLE, RED];

/// How a line is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stroke {
    Solid,
    Dashed,
}

/// One line of a panel.
#[derive(Debug, Clone)]
pub struct Line {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub color: RGBColor,
    pub stroke: Stroke,
    pub width: u32,
}

impl Line {
    pub fn new(
        label: impl Into<String>,
        points: Vec<(f64, f64)>,
        color: RGBColor,
        stroke: Stroke,
    ) -> Line {
        Line {
            label: label.into(),
            points: decimate(&points, BUCKETS),
            color,
            stroke,
            width: if stroke == Stroke::Solid { 2 } else { 1 },
        }
    }
}

/// One panel: lines over a shared x axis.
#[derive(Debug, Clone)]
pub struct Panel {
    pub title: String,
    pub y_label: String,
    pub lines: Vec<Line>,
}

/// A bucket's lowest or highest point so far, if any.
type Point = Option<(f64, f64)>;

/// The min and the max of each of `buckets` equal spans of x, in x order; series shorter than
/// `2 * buckets` are returned as they are. Non-finite values are skipped.
pub fn decimate(points: &[(f64, f64)], buckets: usize) -> Vec<(f64, f64)> {
    if points.len() <= 2 * buckets || buckets == 0 {
        return points.to_vec();
    }
    let (x0, x1) = (points[0].0, points[points.len() - 1].0);
    let span = (x1 - x0).max(f64::MIN_POSITIVE);
    let mut out = Vec::with_capacity(2 * buckets);
    let mut k = 0;
    for b in 0..buckets {
        let end = x0 + span * (b + 1) as f64 / buckets as f64;
        let (mut lo, mut hi): (Point, Point) = (None, None);
        while k < points.len() && (points[k].0 <= end || b + 1 == buckets) {
            let p = points[k];
            if p.1.is_finite() {
                if lo.is_none_or(|l| p.1 < l.1) {
                    lo = Some(p);
                }
                if hi.is_none_or(|h| p.1 > h.1) {
                    hi = Some(p);
                }
            }
            k += 1;
        }
        match (lo, hi) {
            (Some(l), Some(h)) if l.0 <= h.0 => out.extend([l, h]),
            (Some(l), Some(h)) => out.extend([h, l]),
            _ => {}
        }
        if lo.is_some_and(|l| hi.is_some_and(|h| l == h)) {
            out.pop();
        }
    }
    out
}

/// Tick label text with as many decimals as the axis span needs, and no "-0".
pub fn tick_label(v: f64, span: f64) -> String {
    let step = span.abs().max(1e-300) / 5.0;
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    if decimals > 4 {
        // Tiny spans (sub-micrometre errors): scientific, short enough for the label area.
        let scale = 10f64.powi(-(decimals as i32));
        let r = (v / scale).round();
        return if r == 0.0 { "0".into() } else { format!("{:.0}e-{decimals}", r) };
    }
    let s = format!("{v:.decimals$}");
    if s.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

fn y_range(lines: &[Line]) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in lines.iter().flat_map(|l| &l.points).filter(|p| p.1.is_finite()) {
        lo = lo.min(p.1);
        hi = hi.max(p.1);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(hi.abs().max(lo.abs()) * 1e-3).max(1e-9);
    (lo - pad, hi + pad)
}

fn x_range(panels: &[Panel]) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in panels.iter().flat_map(|p| &p.lines).flat_map(|l| &l.points) {
        lo = lo.min(p.0);
        hi = hi.max(p.0);
    }
    if !lo.is_finite() || hi <= lo {
        return (0.0, 1.0);
    }
    (lo, hi)
}

fn perr(path: &Path) -> impl Fn(String) -> ReportError + '_ {
    move |e| ReportError::Plot { path: path.display().to_string(), reason: e }
}

fn draw_panels<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    panels: &[Panel],
    cols: usize,
    x_label: &str,
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(|e| e.to_string())?;
    let rows = panels.len().div_ceil(cols.max(1));
    let (x0, x1) = x_range(panels);
    for (panel, area) in panels.iter().zip(root.split_evenly((rows, cols.max(1))).iter()) {
        let (lo, hi) = y_range(&panel.lines);
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(85)
            .build_cartesian_2d(x0..x1, lo..hi)
            .map_err(|e| e.to_string())?;
        let (xs, ys) = (x1 - x0, hi - lo);
        chart
            .configure_mesh()
            .light_line_style(WHITE.mix(0.0))
            .x_desc(x_label)
            .y_desc(&panel.y_label)
            .x_labels(6)
            .y_labels(5)
            .x_label_formatter(&|v| tick_label(*v, xs))
            .y_label_formatter(&|v| tick_label(*v, ys))
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(|e| e.to_string())?;
        for line in &panel.lines {
            let style = line.color.stroke_width(line.width);
            let legend =
                move |(x, y): (i32, i32)| PathElement::new(vec![(x, y), (x + 18, y)], style);
            let pts = line.points.iter().copied();
            let series = match line.stroke {
                Stroke::Solid => chart.draw_series(LineSeries::new(pts, style)),
                Stroke::Dashed => chart.draw_series(DashedLineSeries::new(pts, 6, 4, style)),
            };
            series.map_err(|e| e.to_string())?.label(line.label.clone()).legend(legend);
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 12))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .draw()
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())
}

/// The PNG and SVG files of figure `stem` in `dir`.
pub fn files(dir: &Path, stem: &str) -> (PathBuf, PathBuf) {
    (dir.join(format!("{stem}.png")), dir.join(format!("{stem}.svg")))
}

/// Stacked panels (`cols` per row), as `stem.png` and `stem.svg` in `dir`.
pub fn panels(
    dir: &Path,
    stem: &str,
    title: &str,
    panels: &[Panel],
    cols: usize,
    x_label: &str,
) -> Result<(), ReportError> {
    register_font();
    let rows = panels.len().div_ceil(cols.max(1)).max(1) as u32;
    let size = (560 * cols.max(1) as u32, 40 + 230 * rows);
    let (png, svg) = files(dir, stem);
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        draw_panels(&root, title, panels, cols, x_label).map_err(perr(&svg))?;
    }
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw_panels(&root, title, panels, cols, x_label).map_err(perr(&png))?;
    }
    write_png(&png, size, &buf)
}

fn draw_bars<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    x_label: &str,
    labels: &[String],
    values: &[f64],
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let top = values.iter().copied().filter(|v| v.is_finite()).fold(0.0, f64::max).max(1e-9) * 1.12;
    let n = labels.len().max(1);
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(170)
        .build_cartesian_2d(0.0..top, (0..n).into_segmented())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .x_desc(x_label)
        .y_labels(n)
        .x_label_formatter(&|v| tick_label(*v, top))
        .y_label_formatter(&|y| match y {
            SegmentValue::CenterOf(i) => labels.get(*i).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|e| e.to_string())?;
    chart
        .draw_series(values.iter().enumerate().map(|(i, v)| {
            let mut bar = Rectangle::new(
                [(0.0, SegmentValue::Exact(i)), (*v, SegmentValue::Exact(i + 1))],
                BLUE.mix(0.8).filled(),
            );
            bar.set_margin(2, 2, 0, 0);
            bar
        }))
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

/// A horizontal bar chart (one bar per label, names readable), as `stem.png` and `stem.svg`.
pub fn bars(
    dir: &Path,
    stem: &str,
    title: &str,
    x_label: &str,
    labels: &[String],
    values: &[f64],
) -> Result<(), ReportError> {
    register_font();
    if labels.len() != values.len() {
        return Err(ReportError::Length {
            name: title.to_string(),
            expected: labels.len(),
            got: values.len(),
        });
    }
    let size = (900, 100 + 20 * labels.len().max(1) as u32);
    let (png, svg) = files(dir, stem);
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        draw_bars(&root, title, x_label, labels, values).map_err(perr(&svg))?;
    }
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw_bars(&root, title, x_label, labels, values).map_err(perr(&png))?;
    }
    write_png(&png, size, &buf)
}

fn write_png(path: &Path, (w, h): (u32, u32), rgb: &[u8]) -> Result<(), ReportError> {
    let io = |e: String| ReportError::Io { path: path.display().to_string(), reason: e };
    let file = std::fs::File::create(path).map_err(|e| io(e.to_string()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Best);
    let mut writer = enc.write_header().map_err(|e| io(e.to_string()))?;
    writer.write_image_data(rgb).map_err(|e| io(e.to_string()))?;
    writer.finish().map_err(|e| io(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_keeps_the_extremes_and_bounds_the_size() {
        let mut pts: Vec<(f64, f64)> =
            (0..20_000).map(|k| (k as f64 * 1e-3, (k as f64 * 1e-3).sin())).collect();
        pts[12_345].1 = 7.0;
        pts[777].1 = -3.0;
        let d = decimate(&pts, 300);
        assert!(d.len() <= 600, "{}", d.len());
        assert!(d.contains(&pts[12_345]) && d.contains(&pts[777]));
        assert!(d.windows(2).all(|w| w[0].0 <= w[1].0), "x order kept");
        // Short series are drawn as they are.
        assert_eq!(decimate(&pts[..100], 300), pts[..100].to_vec());
    }

    #[test]
    fn tick_labels_have_the_needed_decimals_and_no_negative_zero() {
        assert_eq!(tick_label(-0.00001, 1.0), "0.0");
        assert_eq!(tick_label(0.26, 1.0), "0.3");
        assert_eq!(tick_label(0.0012, 0.004), "0.0012");
        assert_eq!(tick_label(1500.0, 4000.0), "1500");
        assert_ne!(tick_label(0.001, 0.004), tick_label(0.002, 0.004));
        // Tiny spans: short scientific labels, distinct, no "-0".
        assert_eq!(tick_label(2e-9, 1e-8), "2e-9");
        assert_eq!(tick_label(-1e-12, 1e-8), "0");
        assert_ne!(tick_label(1e-6, 5e-6), tick_label(2e-6, 5e-6));
    }
}
