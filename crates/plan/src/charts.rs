//! Charts of a report, drawn once per backend so the SVG and the PNG carry the same title, axis
//! labels with units, round ticks, legend and error bars (plotters; DejaVu Sans embedded, so no
//! font is needed on the machine).

use crate::error::{Result, StudyError};
use hilo_core::fs::write_atomic;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::path::Path;

/// Colours of series, in order (colour-blind-safe).
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(230, 159, 0),
    RGBColor(0, 158, 115),
    RGBColor(213, 94, 0),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
    RGBColor(120, 120, 120),
    RGBColor(240, 228, 66),
];

const W: u32 = 900;
const H: u32 = 540;

fn fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // Registration fails only for a malformed font; the embedded one is not.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

fn err(what: &str, e: impl std::fmt::Display) -> StudyError {
    StudyError::Picture { what: what.to_owned(), message: e.to_string() }
}

/// A chart that draws itself on any plotters backend.
pub trait Chart {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>;
}

/// Draws a chart on an SVG and a PNG of the same size and writes `<dir>/<stem>.svg` and `.png`.
pub fn save(dir: &Path, stem: &str, chart: &impl Chart) -> Result<()> {
    fonts();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(stem, e))?;
        chart.draw(&root)?;
        root.present().map_err(|e| err(stem, e))?;
    }
    write_atomic(&dir.join(format!("{stem}.svg")), svg.as_bytes())?;
    let mut rgb = vec![255u8; (W * H * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(stem, e))?;
        chart.draw(&root)?;
        root.present().map_err(|e| err(stem, e))?;
    }
    Ok(write_atomic(&dir.join(format!("{stem}.png")), &png(&rgb, W, H, stem)?)?)
}

/// RGB bytes to PNG (through tiny-skia, which the pictures use too).
pub fn png(rgb: &[u8], w: u32, h: u32, what: &str) -> Result<Vec<u8>> {
    let mut pm = tiny_skia::Pixmap::new(w, h).ok_or_else(|| err(what, "empty picture"))?;
    for (px, c) in pm.pixels_mut().iter_mut().zip(rgb.chunks_exact(3)) {
        *px = tiny_skia::PremultipliedColorU8::from_rgba(c[0], c[1], c[2], 255).unwrap_or(*px);
    }
    pm.encode_png().map_err(|e| err(what, e))
}

/// A series of points with error bars: (x, y, low, high) and a legend label.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64, f64, f64)>,
    /// Join the points with a line.
    pub line: bool,
}

/// An x–y chart of series with error bars.
#[allow(missing_debug_implementations)]
pub struct XY<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub x: (f64, f64),
    pub y: (f64, f64),
    pub series: &'a [Series],
    /// Tick label of an x value (e.g. dollars).
    pub x_fmt: &'a dyn Fn(&f64) -> String,
    /// Text placed under points: (x, y, text).
    pub notes: &'a [(f64, f64, String)],
}

impl Chart for XY<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()> {
        let e = |x: DrawingAreaErrorKind<DB::ErrorType>| err(self.title, x);
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(self.x.0..self.x.1, self.y.0..self.y.1)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(self.x_label)
            .y_desc(self.y_label)
            .x_label_formatter(self.x_fmt)
            .y_label_formatter(&|v| format!("{v:.2}"))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        for (k, s) in self.series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            if s.line {
                chart
                    .draw_series(LineSeries::new(s.points.iter().map(|p| (p.0, p.1)), c.stroke_width(2)))
                    .map_err(e)?;
            }
            chart
                .draw_series(s.points.iter().map(|p| ErrorBar::new_vertical(p.0, p.2, p.1, p.3, c.filled(), 8)))
                .map_err(e)?;
            chart
                .draw_series(s.points.iter().map(|p| Circle::new((p.0, p.1), 5, c.filled())))
                .map_err(e)?
                .label(s.label.clone())
                .legend(move |(x, y)| Circle::new((x + 8, y), 5, c.filled()));
        }
        for (x, y, t) in self.notes {
            chart
                .draw_series(std::iter::once(Text::new(
                    t.clone(),
                    (*x, *y),
                    ("sans-serif", 13).into_font().color(&BLACK),
                )))
                .map_err(e)?;
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight, self.title)
    }
}

/// The legend box of every chart, at `pos`.
fn legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    pos: SeriesLabelPosition,
    title: &str,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(pos)
        .label_font(("sans-serif", 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| err(title, x))
}

/// One bar group's series: its name, and per category a value with its [low, high] range.
pub type BarSeries = (String, Vec<Option<(f64, f64, f64)>>);

/// Grouped bars with error bars: categories along x, one bar per series in each.
#[derive(Debug)]
pub struct Bars<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub categories: &'a [String],
    /// Per series: label and, per category, (value, low, high) or None.
    pub series: &'a [BarSeries],
    pub y_max: f64,
}

impl Chart for Bars<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()> {
        let e = |x: DrawingAreaErrorKind<DB::ErrorType>| err(self.title, x);
        let n = self.categories.len().max(1);
        let cats = self.categories.to_vec();
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..n as f64, 0.0..self.y_max)
            .map_err(e)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc(self.x_label)
            .y_desc(self.y_label)
            .x_labels(n * 2 + 1)
            .x_label_formatter(&|v| {
                let i = v.floor() as usize;
                if (v - i as f64 - 0.5).abs() < 0.26 { cats.get(i).cloned().unwrap_or_default() } else { String::new() }
            })
            .y_label_formatter(&|v| format!("{v:.2}"))
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 16))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        let k = self.series.len().max(1);
        let w = 0.8 / k as f64;
        for (si, (label, values)) in self.series.iter().enumerate() {
            let c = PALETTE[si % PALETTE.len()];
            let bars: Vec<(f64, (f64, f64, f64))> = values
                .iter()
                .enumerate()
                .filter_map(|(ci, v)| v.map(|v| (ci as f64 + 0.1 + w * si as f64, v)))
                .collect();
            chart
                .draw_series(bars.iter().map(|(x0, v)| Rectangle::new([(*x0, 0.0), (*x0 + 0.9 * w, v.0)], c.filled())))
                .map_err(e)?
                .label(label.clone())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
            chart
                .draw_series(
                    bars.iter().map(|(x0, v)| ErrorBar::new_vertical(x0 + 0.45 * w, v.1, v.0, v.2, BLACK.filled(), 6)),
                )
                .map_err(e)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight, self.title)
    }
}

/// `$12,500`.
pub fn dollars(v: &f64) -> String {
    let n = v.round() as i64;
    let s = n.abs().to_string();
    let mut out = String::new();
    for (i, ch) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(ch);
    }
    format!("{}${out}", if n < 0 { "-" } else { "" })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dollars_read_like_prices() {
        assert_eq!(dollars(&10_000.0), "$10,000");
        assert_eq!(dollars(&22_750.4), "$22,750");
        assert_eq!(dollars(&950.0), "$950");
    }
}
