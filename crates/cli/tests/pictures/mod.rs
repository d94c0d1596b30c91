//! Whether a picture carries text where a reader looks for it: a chart's title band, a map's
//! colour key (top left) and the "N" of its north arrow (top right).
//!
//! Text is found as dark ink beside light paper: columns of a region holding a dark pixel (luma
//! < 100) with a light one (luma > 160) within two pixels. Glyphs are separated by gaps, so a line
//! of text gives one run of such columns per letter or word; a region holding at most a bar, a
//! swatch or a scatter of points gives few.

#![allow(dead_code)]

use std::path::Path;
use tiny_skia::Pixmap;

/// A pixel rectangle: x0, y0, x1, y1.
pub type Region = (i64, i64, i64, i64);

#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// A plotters chart: a title across the top.
    Chart,
    /// A top-down map: a colour key top left, a north arrow with its "N" top right.
    Map,
}

fn luma(pm: &Pixmap, x: i64, y: i64) -> Option<f32> {
    if x < 0 || y < 0 || x >= pm.width() as i64 || y >= pm.height() as i64 {
        return None;
    }
    let p = pm.pixel(x as u32, y as u32)?.demultiply();
    Some(0.299 * p.red() as f32 + 0.587 * p.green() as f32 + 0.114 * p.blue() as f32)
}

/// Runs of columns holding ink on paper in the region `x0..x1` × `y0..y1` (clipped).
pub fn text_runs(pm: &Pixmap, (x0, y0, x1, y1): Region) -> usize {
    let ink_col = |x: i64| {
        (y0..y1).any(|y| {
            luma(pm, x, y).is_some_and(|l| l < 100.0)
                && (-2..=2).any(|dx| (-2..=2).any(|dy| luma(pm, x + dx, y + dy).is_some_and(|l| l > 160.0)))
        })
    };
    let mut runs = 0;
    let mut inside = false;
    for x in x0.max(0)..x1.min(pm.width() as i64) {
        let ink = ink_col(x);
        if ink && !inside {
            runs += 1;
        }
        inside = ink;
    }
    runs
}

/// Panics (naming the file and region) when a picture has no text where its kind puts it.
pub fn assert_labelled(path: &Path, kind: Kind) {
    let pm = Pixmap::load_png(path).unwrap_or_else(|e| panic!("{}: not a PNG: {e}", path.display()));
    let w = pm.width() as i64;
    let checks: Vec<(&str, Region, usize)> = match kind {
        Kind::Chart => vec![("title", (0, 0, w, 50), 6)],
        Kind::Map => vec![("colour key", (8, 8, 8 + 300, 40), 6), ("north arrow's N", (w - 50, 52, w, 80), 1)],
    };
    for (what, region, min) in checks {
        let runs = text_runs(&pm, region);
        assert!(runs >= min, "{}: {what} region {region:?} holds {runs} glyph runs, expected >= {min}", path.display());
    }
}

/// The check can fail: paper with a bar and a swatch but no text is not labelled.
pub fn check_can_fail() {
    let mut pm = Pixmap::new(400, 120).expect("pixmap");
    pm.fill(tiny_skia::Color::WHITE);
    let mut black = tiny_skia::Paint::default();
    black.set_color_rgba8(0, 0, 0, 255);
    for (x, w) in [(16.0, 14.0), (60.0, 200.0)] {
        let r = tiny_skia::Rect::from_xywh(x, 14.0, w, 14.0).expect("rect");
        pm.fill_rect(r, &black, tiny_skia::Transform::identity(), None);
    }
    assert!(text_runs(&pm, (8, 8, 308, 40)) < 6);
}
