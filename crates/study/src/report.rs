//! The study report: `report.md`, `report.json` and figures (SVG with labels; PNG with the same
//! geometry — the PNG renderer has no fonts, so its labels are in the SVG and the report).

use crate::error::{Result, StudyError};
use crate::files::write_atomic;
use crate::run::{Pictures, Report, ResultsBy};
use crate::study::Configuration;
use glam::{Vec2, Vec3};
use hilo_core::Box3;
use hilo_eval::EvalBox;
use hilo_fusion::data::Frame;
use std::fmt::Write as _;
use std::path::Path;

const COLORS: [(u8, u8, u8); 6] =
    [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)];

/// A chart in data coordinates, rendered to SVG and PNG.
struct Chart {
    w: f32,
    h: f32,
    x: (f32, f32),
    y: (f32, f32),
    svg: String,
    pix: Option<tiny_skia::Pixmap>,
}

impl Chart {
    const M: f32 = 60.0;

    fn new(title: &str, xl: &str, yl: &str, x: (f32, f32), y: (f32, f32)) -> Chart {
        let (w, h) = (720.0, 440.0);
        let mut c = Chart { w, h, x, y, svg: String::new(), pix: tiny_skia::Pixmap::new(w as u32, h as u32) };
        if let Some(p) = &mut c.pix {
            p.fill(tiny_skia::Color::WHITE);
        }
        let _ = write!(
            c.svg,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="100%" height="100%" fill="white"/><text x="{}" y="20" text-anchor="middle" font-size="15">{}</text><text x="{}" y="{}" text-anchor="middle">{}</text><text x="14" y="{}" transform="rotate(-90 14 {})" text-anchor="middle">{}</text>"#,
            w / 2.0,
            esc(title),
            w / 2.0,
            h - 10.0,
            esc(xl),
            h / 2.0,
            h / 2.0,
            esc(yl)
        );
        // Axes and ticks.
        let (x0, y0, x1, y1) = (Self::M, h - Self::M, w - 20.0, 35.0);
        c.raw_line((x0, y0), (x1, y0), (0, 0, 0), 1.0);
        c.raw_line((x0, y0), (x0, y1), (0, 0, 0), 1.0);
        for k in 0..=4 {
            let fy = y.0 + (y.1 - y.0) * k as f32 / 4.0;
            let py = c.py(fy);
            c.raw_line((x0 - 4.0, py), (x1, py), (220, 220, 220), 0.5);
            let _ = write!(c.svg, r#"<text x="{}" y="{}" text-anchor="end">{:.2}</text>"#, x0 - 6.0, py + 4.0, fy);
        }
        c
    }

    fn px(&self, v: f32) -> f32 {
        Self::M + (v - self.x.0) / (self.x.1 - self.x.0).max(1e-9) * (self.w - Self::M - 20.0)
    }

    fn py(&self, v: f32) -> f32 {
        (self.h - Self::M) - (v - self.y.0) / (self.y.1 - self.y.0).max(1e-9) * (self.h - Self::M - 35.0)
    }

    fn raw_line(&mut self, a: (f32, f32), b: (f32, f32), c: (u8, u8, u8), width: f32) {
        let _ = write!(
            self.svg,
            r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="rgb({},{},{})" stroke-width="{width}"/>"#,
            a.0, a.1, b.0, b.1, c.0, c.1, c.2
        );
        if let Some(p) = &mut self.pix {
            let mut pb = tiny_skia::PathBuilder::new();
            pb.move_to(a.0, a.1);
            pb.line_to(b.0, b.1);
            if let Some(path) = pb.finish() {
                let mut paint = tiny_skia::Paint::default();
                paint.set_color_rgba8(c.0, c.1, c.2, 255);
                paint.anti_alias = true;
                p.stroke_path(
                    &path,
                    &paint,
                    &tiny_skia::Stroke { width, ..Default::default() },
                    tiny_skia::Transform::identity(),
                    None,
                );
            }
        }
    }

    fn rect(&mut self, x0: f32, x1: f32, y: f32, c: (u8, u8, u8)) {
        let (a, b) = (self.px(x0), self.px(x1));
        let (top, bottom) = (self.py(y.max(self.y.0)), self.py(self.y.0));
        let _ = write!(
            self.svg,
            r#"<rect x="{a}" y="{top}" width="{}" height="{}" fill="rgb({},{},{})"/>"#,
            b - a,
            bottom - top,
            c.0,
            c.1,
            c.2
        );
        if let (Some(p), Some(r)) = (&mut self.pix, tiny_skia::Rect::from_ltrb(a, top, b, bottom)) {
            let mut paint = tiny_skia::Paint::default();
            paint.set_color_rgba8(c.0, c.1, c.2, 255);
            p.fill_rect(r, &paint, tiny_skia::Transform::identity(), None);
        }
    }

    fn point(&mut self, x: f32, y: f32, c: (u8, u8, u8)) {
        let (a, b) = (self.px(x), self.py(y));
        let _ = write!(self.svg, r#"<circle cx="{a}" cy="{b}" r="5" fill="rgb({},{},{})"/>"#, c.0, c.1, c.2);
        if let (Some(p), Some(path)) = (&mut self.pix, tiny_skia::PathBuilder::from_circle(a, b, 5.0)) {
            let mut paint = tiny_skia::Paint::default();
            paint.set_color_rgba8(c.0, c.1, c.2, 255);
            p.fill_path(&path, &paint, tiny_skia::FillRule::Winding, tiny_skia::Transform::identity(), None);
        }
    }

    fn line(&mut self, a: (f32, f32), b: (f32, f32), c: (u8, u8, u8)) {
        let (pa, pb) = ((self.px(a.0), self.py(a.1)), (self.px(b.0), self.py(b.1)));
        self.raw_line(pa, pb, c, 2.0);
    }

    fn text(&mut self, x: f32, y: f32, s: &str, anchor: &str) {
        let _ = write!(
            self.svg,
            r#"<text x="{}" y="{}" text-anchor="{anchor}">{}</text>"#,
            self.px(x),
            self.py(y) + 14.0,
            esc(s)
        );
    }

    fn legend(&mut self, items: &[(String, (u8, u8, u8))]) {
        for (k, (name, c)) in items.iter().enumerate() {
            let (x, y) = (self.w - 200.0, 45.0 + 16.0 * k as f32);
            let _ = write!(
                self.svg,
                r#"<rect x="{x}" y="{}" width="10" height="10" fill="rgb({},{},{})"/><text x="{}" y="{}">{}</text>"#,
                y - 9.0,
                c.0,
                c.1,
                c.2,
                x + 14.0,
                y,
                esc(name)
            );
        }
    }

    fn save(self, dir: &Path, stem: &str) -> Result<()> {
        write_atomic(&dir.join(format!("{stem}.svg")), format!("{}</svg>\n", self.svg).as_bytes())?;
        if let Some(p) = self.pix {
            let png = p
                .encode_png()
                .map_err(|e| StudyError::Picture { what: format!("chart {stem}"), message: e.to_string() })?;
            write_atomic(&dir.join(format!("{stem}.png")), &png)?;
        }
        Ok(())
    }
}

/// How a configuration was placed, and whether it was solved (a single-modality configuration
/// takes its poses from a sibling: its own multimodal objective is zero, so there is no gap).
fn placement_status(c: &crate::run::ConfigSummary) -> (String, bool) {
    if !c.placement_solved {
        (c.placement_method.clone(), false)
    } else if c.placement_proven_optimal {
        ("proven optimal".into(), true)
    } else {
        (format!("not proven, gap {:.2}%", 100.0 * c.placement_gap), true)
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

fn mean_over_seeds(
    r: &Report,
    conf: &str,
    preset: &str,
    f: impl Fn(&crate::run::Entry) -> f64,
) -> Option<(f64, f64, f64)> {
    let v: Vec<f64> = r.entries.iter().filter(|e| e.configuration == conf && e.preset == preset).map(f).collect();
    if v.is_empty() {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    Some((m, v.iter().copied().fold(f64::INFINITY, f64::min), v.iter().copied().fold(f64::NEG_INFINITY, f64::max)))
}

fn to_box(b: &EvalBox) -> Box3 {
    Box3::new(
        Vec3::new(b.translation[0] as f32, b.translation[1] as f32, b.translation[2] as f32),
        b.size[1] as f32,
        b.size[0] as f32,
        b.size[2] as f32,
        b.yaw() as f32,
    )
}

/// A bird's-eye picture of one validation frame: points, ground truth (green; yellow when
/// missed), detections with score ≥ 0.3 (blue when within 2 m of a same-class box, red when
/// false).
fn detection_png(frame: &Frame, gboxes: &[EvalBox], preds: &[(String, Vec<EvalBox>)], path: &Path) -> Result<()> {
    let pboxes: Vec<EvalBox> = preds
        .iter()
        .find(|p| p.0 == frame.sample_token)
        .map(|p| p.1.iter().filter(|b| b.detection_score >= 0.3).cloned().collect())
        .unwrap_or_default();
    let mut canvas = crate::render::blank_canvas(Vec2::splat(-55.0), Vec2::splat(55.0), 7.0)?;
    let dots: Vec<(Vec2, (u8, u8, u8))> = frame
        .lidar
        .iter()
        .map(|p| (Vec2::new(p[0], p[1]), (150, 150, 150)))
        .chain(frame.radar.iter().map(|p| (Vec2::new(p[0], p[1]), (230, 0, 230))))
        .collect();
    canvas.dots(&dots, 1.0);
    let near = |a: &EvalBox, b: &EvalBox| {
        a.detection_name == b.detection_name
            && (a.translation[0] - b.translation[0]).hypot(a.translation[1] - b.translation[1]) <= 2.0
    };
    for g in gboxes {
        let col = if pboxes.iter().any(|p| near(p, g)) { (0, 200, 0) } else { (255, 220, 0) };
        canvas.boxes(&[to_box(g)], col);
    }
    for p in &pboxes {
        let col = if gboxes.iter().any(|g| near(p, g)) { (40, 120, 255) } else { (255, 40, 40) };
        canvas.boxes(&[to_box(p)], col);
    }
    write_atomic(path, &canvas.png()?)
}

pub fn write(
    out: &Path,
    r: &Report,
    results: &ResultsBy,
    pictures: &Pictures,
    placements: &Path,
    configs: &[Configuration],
) -> Result<()> {
    let fig = out.join("figures");
    std::fs::create_dir_all(fig.join("detections")).map_err(|e| StudyError::io(&fig, e))?;
    crate::files::write_json(&out.join("report.json"), r)?;
    let presets: Vec<String> = r.profile.presets.clone();
    // mAP against cost.
    let max_cost = r.configurations.iter().map(|c| c.cost_usd).fold(0.0, f64::max) as f32;
    let max_map = r.entries.iter().map(|e| e.bootstrap.mean_ap.hi.max(e.mean_ap)).fold(0.05, f64::max) as f32;
    let mut ch = Chart::new(
        "mAP against hardware cost",
        "cost (USD)",
        "mAP (val)",
        (0.0, max_cost * 1.1),
        (0.0, max_map * 1.15),
    );
    let mut legend = Vec::new();
    for (k, p) in presets.iter().enumerate() {
        let col = COLORS[k % COLORS.len()];
        let mut pts: Vec<(f32, f32)> = r
            .configurations
            .iter()
            .filter_map(|c| mean_over_seeds(r, &c.name, p, |e| e.mean_ap).map(|m| (c.cost_usd as f32, m.0 as f32)))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        for w in pts.windows(2) {
            ch.line(w[0], w[1], col);
        }
        for &(x, y) in &pts {
            ch.point(x, y, col);
        }
        legend.push((p.clone(), col));
    }
    for c in &r.configurations {
        ch.text(c.cost_usd as f32, 0.0, &c.name, "middle");
    }
    ch.legend(&legend);
    ch.save(&fig, "map_vs_cost")?;
    // Pedestrian AP per configuration and preset.
    let max_ped = r.entries.iter().filter_map(|e| e.class_ap.get("pedestrian").copied()).fold(0.05, f64::max) as f32;
    let n = r.configurations.len() as f32;
    let mut ch = Chart::new(
        "Pedestrian AP per configuration",
        "configuration",
        "pedestrian AP (val)",
        (0.0, n),
        (0.0, max_ped * 1.15),
    );
    for (i, c) in r.configurations.iter().enumerate() {
        let w = 0.8 / presets.len().max(1) as f32;
        for (k, p) in presets.iter().enumerate() {
            if let Some(m) = mean_over_seeds(r, &c.name, p, |e| e.class_ap.get("pedestrian").copied().unwrap_or(0.0)) {
                let x0 = i as f32 + 0.1 + w * k as f32;
                ch.rect(x0, x0 + w * 0.9, m.0 as f32, COLORS[k % COLORS.len()]);
            }
        }
        ch.text(i as f32 + 0.5, 0.0, &c.name, "middle");
    }
    ch.legend(&legend);
    ch.save(&fig, "pedestrian_ap")?;
    // Coverage maps and detection pictures.
    for c in configs {
        let src = placements.join(format!("{}.png", c.slug()));
        if src.exists() {
            std::fs::copy(&src, fig.join(format!("coverage_{}.png", c.slug()))).map_err(|e| StudyError::io(&src, e))?;
        }
        for p in &presets {
            if let (Some(pred), Some((frame, gboxes))) =
                (results.get(&(c.name.clone(), p.clone(), 0)), pictures.get(&c.name))
            {
                detection_png(frame, gboxes, pred, &fig.join("detections").join(format!("{}__{}.png", c.slug(), p)))?;
            }
        }
    }
    // Markdown.
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# hilo study report\n\nStudy `{}`, profile `{}`, {} seed(s); generated by `hilo study{} --out <dir>{}`; this invocation took {:.0} s on this machine (stages already complete in the folder are reused).\n",
        r.study,
        r.profile.name,
        r.seeds,
        if r.study.starts_with("<embedded>") { String::new() } else { format!(" {}", r.study) },
        if r.profile.name == "default" { String::new() } else { format!(" --profile {}", r.profile.name) },
        r.seconds
    );
    let d = &r.profile.dataset;
    let _ = writeln!(
        md,
        "Dataset per configuration (same traffic seeds for every configuration): training {} scenes × {} s at {} Hz; validation {} other scenes × {} s at {} Hz. Each detector trained on {} samples.\n",
        d.scenes, d.seconds, d.rate_hz, d.val_scenes, d.val_seconds, d.val_rate_hz, r.profile.train_samples
    );
    let _ = writeln!(
        md,
        "## Configurations\n\n| configuration | cost (USD) | central coverage | placement | sensors |\n|---|---:|---:|---|---|"
    );
    for c in &r.configurations {
        let (status, solved) = placement_status(c);
        let how = if solved { format!("{status} in {:.2} s", c.placement_seconds) } else { status };
        let _ = writeln!(
            md,
            "| {} | {:.0} | {:.1}% | {} | {} |",
            c.name,
            c.cost_usd,
            c.central_coverage * 100.0,
            esc(&how),
            c.sensors.join(", ")
        );
    }
    if !r.cost_reduction.is_empty() {
        let _ = writeln!(
            md,
            "\nCost of the cheapest configuration against the others: {}.",
            r.cost_reduction
                .iter()
                .map(|(k, v)| format!("−{:.1}% against {k}", v * 100.0))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let _ = writeln!(
        md,
        "\n## Accuracy (validation split, nuScenes metric; 95% scene-bootstrap intervals)\n\n| configuration | preset | mAP | NDS | car AP | pedestrian AP | training | inference |\n|---|---|---|---|---|---|---:|---:|"
    );
    for e in &r.entries {
        let ci = |k: &str| {
            e.bootstrap
                .class_ap
                .get(k)
                .map_or("–".to_owned(), |i| format!("{:.3} [{:.3}, {:.3}]", i.estimate, i.lo, i.hi))
        };
        let _ = writeln!(
            md,
            "| {} | {}{} | {:.3} [{:.3}, {:.3}] | {:.3} [{:.3}, {:.3}] | {} | {} | {:.0} s ({} samples) | {:.0} ms/frame |",
            e.configuration,
            e.preset,
            if r.seeds > 1 { format!(" (seed {})", e.seed) } else { String::new() },
            e.mean_ap,
            e.bootstrap.mean_ap.lo,
            e.bootstrap.mean_ap.hi,
            e.nd_score,
            e.bootstrap.nd_score.lo,
            e.bootstrap.nd_score.hi,
            ci("car"),
            ci("pedestrian"),
            e.train_seconds,
            e.samples,
            e.ms_per_frame
        );
    }
    let _ = writeln!(
        md,
        "\nPer-class AP of every detector is in `report.json` (`entries[].class_ap`, with intervals in `entries[].bootstrap.class_ap`)."
    );
    if !r.comparisons.is_empty() {
        let n_val = r.entries.first().map_or(0, |e| e.bootstrap.scenes);
        let _ = writeln!(
            md,
            "\n## Is the difference real? (paired scene bootstrap, same traffic)\n\nEach configuration is scored on its own ground truth (the boxes its sensors saw); every replicate draws the same validation scenes for both. With {n_val} validation scene(s) the intervals understate the uncertainty of a different day's traffic: more scenes (`[dataset] scenes`) or `--seeds` narrow the question.\n\n| preset | cheaper (B) | against (A) | mAP B − A [95%] | P[B not better] | pedestrian AP A → B |\n|---|---|---|---|---:|---|"
        );
        for c in &r.comparisons {
            let i = c.paired.mean_ap_diff;
            let verdict = if i.lo > 0.0 {
                "B better"
            } else if i.hi < 0.0 {
                "A better"
            } else {
                "not significant"
            };
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:+.3} [{:+.3}, {:+.3}] ({verdict}) | {:.3} | {:.3} → {:.3} |",
                c.preset,
                c.b,
                c.a,
                i.estimate,
                i.lo,
                i.hi,
                c.paired.p_mean_ap_not_better,
                c.pedestrian_ap_a,
                c.pedestrian_ap_b
            );
        }
    }
    let _ = writeln!(
        md,
        "\n## Figures\n\n![mAP against cost](figures/map_vs_cost.svg)\n\n![pedestrian AP](figures/pedestrian_ap.svg)\n\nCoverage maps (green: LiDAR-hit cells, red: radar-covered, yellow: both): {}\n",
        configs
            .iter()
            .map(|c| format!("[{}](figures/coverage_{}.png)", c.name, c.slug()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        md,
        "Detections on one validation frame (grey LiDAR, magenta radar; ground truth green, missed yellow; detections blue, false red):\n"
    );
    let _ = writeln!(
        md,
        "| configuration | {} |\n|---|{}",
        presets.join(" | "),
        presets.iter().map(|_| "---|").collect::<String>()
    );
    for c in configs {
        let cells: Vec<String> = presets
            .iter()
            .map(|p| {
                if results.contains_key(&(c.name.clone(), p.clone(), 0)) {
                    format!("![{} {}](figures/detections/{}__{}.png)", c.name, p, c.slug(), p)
                } else {
                    "n/a (no radar)".into()
                }
            })
            .collect();
        let _ = writeln!(md, "| {} | {} |", c.name, cells.join(" | "));
    }
    let _ = writeln!(md, "\n## Speed against error\n\n| stage | speed | error paid |\n|---|---|---|");
    for c in &r.configurations {
        let (status, solved) = placement_status(c);
        let paid = if !solved {
            "none: not an optimisation".to_owned()
        } else if c.placement_proven_optimal {
            "none: proven optimal".to_owned()
        } else {
            status
        };
        let _ = writeln!(md, "| placement, {} | {:.2} s | {} |", c.name, c.placement_seconds, esc(&paid));
    }
    let t = &r.tradeoffs;
    for l in &t.los {
        let _ = writeln!(
            md,
            "| visibility of {}, {} line-of-sight sample{} per probe and cell | {:.2} s | mean \\|ΔV\\| {:.4} (max {:.3}) against {} samples; the placement it gives is worth {:.2}% less on that V |",
            t.configuration,
            l.samples_per_probe,
            if l.samples_per_probe == 1 { "" } else { "s" },
            l.seconds,
            l.mean_abs_dv,
            l.max_abs_dv,
            t.los.last().map_or(0, |x| x.samples_per_probe),
            100.0 * l.placement_loss
        );
    }
    for l in &t.limits {
        let _ = writeln!(
            md,
            "| placement under a budget of {:.0} USD (any of {}), time limit {} s | {:.2} s | {}: objective {:.1}, bound {:.1}, gap {:.2}% ({}; greedy {:.1}) |",
            t.budget_usd,
            t.types.join(", "),
            l.time_limit_s,
            l.seconds,
            l.selection,
            l.objective,
            l.bound,
            100.0 * l.gap,
            if l.proven_optimal { "proven optimal" } else { "not proven" },
            t.greedy_objective
        );
    }
    for e in r.entries.iter().filter(|e| e.seed == 0) {
        let _ = writeln!(
            md,
            "| detector {} on {} ({:.2} M parameters) | {:.0} ms/frame, trained in {:.0} s | mAP {:.3} |",
            e.preset,
            e.configuration,
            e.parameters as f64 / 1e6,
            e.ms_per_frame,
            e.train_seconds,
            e.mean_ap
        );
    }
    write_atomic(&out.join("report.md"), md.as_bytes())
}
