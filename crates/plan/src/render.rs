//! Top-down pictures of a scene (tiny-skia raster, PNG): the scene itself, and the canvas the
//! coverage maps, scans, dataset frames and detection pictures are drawn on.

use crate::error::{Result, StudyError};
use glam::{Vec2, Vec3};
use hilo_core::Box3;
use hilo_raycast::scene::layout::point_in_polygon;
use hilo_raycast::{ObjectKind, Scene};
use serde_json::json;
use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Stroke, StrokeDash, Transform};

/// Maps local metres to pixels (y up in the world, down in the image).
struct View {
    min: Vec2,
    max: Vec2,
    scale: f32,
}

impl View {
    fn px(&self, p: Vec2) -> (f32, f32) {
        ((p.x - self.min.x) * self.scale, (self.max.y - p.y) * self.scale)
    }

    fn path(&self, poly: &[Vec2], close: bool) -> Option<tiny_skia::Path> {
        let mut pb = PathBuilder::new();
        let (x, y) = self.px(*poly.first()?);
        pb.move_to(x, y);
        for p in &poly[1..] {
            let (x, y) = self.px(*p);
            pb.line_to(x, y);
        }
        if close {
            pb.close();
        }
        pb.finish()
    }

    fn circle(&self, c: Vec2, r: f32) -> Option<tiny_skia::Path> {
        let (x, y) = self.px(c);
        PathBuilder::from_circle(x, y, (r * self.scale).max(0.75))
    }
}

fn paint(r: u8, g: u8, b: u8, a: u8) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color(Color::from_rgba8(r, g, b, a));
    p.anti_alias = true;
    p
}

/// A picture in progress: the scene drawn, more can be drawn on top.
pub struct Canvas {
    pm: Pixmap,
    view: View,
}

impl std::fmt::Debug for Canvas {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Canvas({}x{} px, {} px/m)", self.pm.width(), self.pm.height(), self.view.scale)
    }
}

impl Canvas {
    fn fill(&mut self, poly: &[Vec2], p: &Paint) {
        if let Some(path) = self.view.path(poly, true) {
            self.pm.fill_path(&path, p, FillRule::EvenOdd, Transform::identity(), None);
        }
    }

    fn stroke(&mut self, pts: &[Vec2], p: &Paint, width_m: f32, dash_m: Option<(f32, f32)>) {
        if let Some(path) = self.view.path(pts, false) {
            let mut s = Stroke { width: (width_m * self.view.scale).max(1.0), ..Stroke::default() };
            if let Some((on, off)) = dash_m {
                s.dash = StrokeDash::new(vec![on * self.view.scale, off * self.view.scale], 0.0);
            }
            self.pm.stroke_path(&path, p, &s, Transform::identity(), None);
        }
    }

    fn outline(&mut self, poly: &[Vec2], p: &Paint, width_px: f32) {
        if let Some(path) = self.view.path(poly, true) {
            let s = Stroke { width: width_px, ..Stroke::default() };
            self.pm.stroke_path(&path, p, &s, Transform::identity(), None);
        }
    }

    fn disc(&mut self, c: Vec2, r_m: f32, p: &Paint) {
        if let Some(path) = self.view.circle(c, r_m) {
            self.pm.fill_path(&path, p, FillRule::Winding, Transform::identity(), None);
        }
    }
}

/// A roundabout's island: grass and shrubs.
const ISLAND: (u8, u8, u8) = (122, 158, 92);

/// Renders the scene top-down at `px_per_m` and returns PNG bytes.
pub fn scene_png(scene: &Scene, px_per_m: f32) -> Result<Vec<u8>> {
    let mut c = scene_canvas(scene, px_per_m)?;
    let mut keys = vec![
        ((70, 70, 74), "roadway"),
        ((214, 209, 199), "sidewalk"),
        ((176, 168, 150), "median"),
        ((141, 110, 99), "building"),
        ((46, 125, 50), "tree crown"),
        ((10, 10, 10), "signal pole and mast arm (mounts)"),
        ((240, 200, 40), "signal head"),
        ((230, 50, 40), "ROI (redder: heavier weight)"),
    ];
    if scene.layout.ring.is_some() {
        keys.insert(3, (ISLAND, "roundabout island"));
    }
    c.legend(&keys);
    c.png()
}

impl Canvas {
    /// The pixel (column, row) of a point on the ground, in metres.
    pub fn px(&self, p: Vec2) -> (f32, f32) {
        self.view.px(p)
    }

    /// PNG bytes of the picture.
    pub fn png(&self) -> Result<Vec<u8>> {
        self.pm.encode_png().map_err(|e| StudyError::Picture { what: "a PNG".into(), message: e.to_string() })
    }

    /// Outlines of boxes (e.g. actors), in an RGB colour, each with a heading tick from its
    /// centre to the middle of its front edge.
    pub fn boxes(&mut self, boxes: &[hilo_core::Box3], rgb: (u8, u8, u8)) {
        let p = paint(rgb.0, rgb.1, rgb.2, 255);
        for b in boxes {
            self.outline(&b.bev_corners(), &p, 2.0);
            let c = b.center.truncate();
            let front = c + b.heading() * (0.5 * b.length_m).max(0.4);
            if let Some(path) = self.view.path(&[c, front], false) {
                self.pm.stroke_path(
                    &path,
                    &p,
                    &Stroke { width: 1.5, ..Stroke::default() },
                    Transform::identity(),
                    None,
                );
            }
        }
    }

    /// Text at a pixel position (its top-left corner), `size` pixels high, in an RGB colour.
    pub fn text(&mut self, at: (f32, f32), text: &str, size: f32, rgb: (u8, u8, u8)) {
        use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
        let Ok(font) = FontRef::try_from_slice(dejavu::sans::regular()) else { return };
        let scaled = font.as_scaled(PxScale::from(size));
        let (w, h) = (self.pm.width() as i64, self.pm.height() as i64);
        let mut x = at.0;
        let y = at.1 + scaled.ascent();
        let mut prev = None;
        for ch in text.chars() {
            let id = font.glyph_id(ch);
            if let Some(p) = prev {
                x += scaled.kern(p, id);
            }
            let glyph = id.with_scale_and_position(PxScale::from(size), ab_glyph::point(x, y));
            x += scaled.h_advance(id);
            prev = Some(id);
            let Some(outlined) = font.outline_glyph(glyph) else { continue };
            let bounds = outlined.px_bounds();
            let data = self.pm.data_mut();
            outlined.draw(|gx, gy, cov| {
                let (px, py) = (bounds.min.x as i64 + gx as i64, bounds.min.y as i64 + gy as i64);
                if px < 0 || py < 0 || px >= w || py >= h || cov <= 0.0 {
                    return;
                }
                let i = 4 * (py * w + px) as usize;
                let a = cov.min(1.0);
                for (k, c) in [rgb.0, rgb.1, rgb.2].into_iter().enumerate() {
                    data[i + k] = (data[i + k] as f32 * (1.0 - a) + c as f32 * a).round() as u8;
                }
                data[i + 3] = 255;
            });
        }
    }

    /// Width in pixels of `text` at `size`.
    pub fn text_width(&self, text: &str, size: f32) -> f32 {
        use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
        let Ok(font) = FontRef::try_from_slice(dejavu::sans::regular()) else { return 0.0 };
        let scaled = font.as_scaled(PxScale::from(size));
        text.chars().map(|c| scaled.h_advance(font.glyph_id(c))).sum()
    }

    /// A colour key in the top-left corner: a swatch and a label per entry, on a light panel.
    pub fn legend(&mut self, items: &[((u8, u8, u8), &str)]) {
        let size = 16.0;
        let line = 22.0;
        let wmax = items.iter().map(|(_, t)| self.text_width(t, size)).fold(0.0, f32::max);
        if let Some(r) = tiny_skia::Rect::from_xywh(8.0, 8.0, wmax + 44.0, line * items.len() as f32 + 12.0) {
            self.pm.fill_rect(r, &paint(255, 255, 255, 215), Transform::identity(), None);
        }
        for (k, (c, t)) in items.iter().enumerate() {
            let y = 14.0 + line * k as f32;
            if let Some(r) = tiny_skia::Rect::from_xywh(16.0, y + 2.0, 14.0, 14.0) {
                self.pm.fill_rect(r, &paint(c.0, c.1, c.2, 255), Transform::identity(), None);
            }
            self.text((38.0, y), t, size, (20, 20, 20));
        }
    }

    /// A scale bar of `len_m` metres in the bottom-left corner, ticked every quarter, labelled.
    pub fn scale_bar(&mut self, len_m: f32) {
        let (h, s) = (self.pm.height() as f32, self.view.scale);
        let (x0, y0) = (20.0, h - 24.0);
        if let Some(r) = tiny_skia::Rect::from_xywh(x0 - 8.0, y0 - 30.0, len_m * s + 60.0, 42.0) {
            self.pm.fill_rect(r, &paint(255, 255, 255, 215), Transform::identity(), None);
        }
        let black = paint(0, 0, 0, 255);
        let mut pb = PathBuilder::new();
        pb.move_to(x0, y0);
        pb.line_to(x0 + len_m * s, y0);
        for k in 0..=4 {
            let x = x0 + len_m * s * k as f32 / 4.0;
            pb.move_to(x, y0);
            pb.line_to(x, y0 - if k % 2 == 0 { 10.0 } else { 6.0 });
        }
        if let Some(path) = pb.finish() {
            self.pm.stroke_path(
                &path,
                &black,
                &Stroke { width: 2.0, ..Stroke::default() },
                Transform::identity(),
                None,
            );
        }
        self.text((x0 + len_m * s + 8.0, y0 - 14.0), &format!("{len_m:.0} m"), 16.0, (0, 0, 0));
    }

    /// A north arrow (+y is north) with its "N", in the top-right corner.
    pub fn north_arrow(&mut self) {
        let w = self.pm.width() as f32;
        let (x, y) = (w - 36.0, 44.0);
        // On a light panel, so it reads on dark canvases too.
        if let Some(r) = tiny_skia::Rect::from_xywh(x - 18.0, y - 30.0, 36.0, 64.0) {
            self.pm.fill_rect(r, &paint(255, 255, 255, 215), Transform::identity(), None);
        }
        let mut pb = PathBuilder::new();
        pb.move_to(x, y - 22.0);
        pb.line_to(x - 10.0, y + 8.0);
        pb.line_to(x, y + 2.0);
        pb.line_to(x + 10.0, y + 8.0);
        pb.close();
        if let Some(path) = pb.finish() {
            self.pm.fill_path(&path, &paint(0, 0, 0, 255), FillRule::Winding, Transform::identity(), None);
        }
        self.text((x - 6.0, y + 10.0), "N", 18.0, (0, 0, 0));
    }

    /// A polyline in an RGB colour, `width_m` wide.
    pub fn line(&mut self, pts: &[Vec2], rgb: (u8, u8, u8), width_m: f32) {
        let p = paint(rgb.0, rgb.1, rgb.2, 255);
        self.stroke(pts, &p, width_m, None);
    }

    /// Dots at local-frame points, each with its own RGB colour and a radius in pixels.
    pub fn dots(&mut self, points: &[(Vec2, (u8, u8, u8))], radius_px: f32) {
        for (q, c) in points {
            let (x, y) = self.view.px(*q);
            if let Some(path) = PathBuilder::from_circle(x, y, radius_px) {
                self.pm.fill_path(&path, &paint(c.0, c.1, c.2, 230), FillRule::Winding, Transform::identity(), None);
            }
        }
    }
}

/// An empty dark canvas over `min..max` (local metres), for pictures without a scene.
pub fn blank_canvas(min: Vec2, max: Vec2, px_per_m: f32) -> Result<Canvas> {
    let size = (max - min) * px_per_m;
    let mut pm = Pixmap::new(size.x.ceil().max(1.0) as u32, size.y.ceil().max(1.0) as u32).ok_or_else(|| {
        StudyError::Picture {
            what: "a canvas".into(),
            message: format!("{:.0}x{:.0} px is empty or too large", size.x, size.y),
        }
    })?;
    pm.fill(Color::from_rgba8(20, 22, 28, 255));
    Ok(Canvas { pm, view: View { min, max, scale: px_per_m } })
}

/// The scene drawn top-down, ready for more layers.
/// The points of one scan, in the scene's local frame, as `hilo scan` draws them.
#[derive(Clone, Copy, Debug)]
pub enum ScanPoints<'a> {
    /// Coloured by height above the ground (cyan at it, red 4 m above).
    Lidar(&'a [hilo_core::LidarPoint]),
    /// Coloured by radial velocity: red approaching, white static, blue receding (±10 m/s).
    Radar(&'a [hilo_core::RadarPoint]),
}

/// A scan drawn over the scene, top-down: its points, the road users' boxes, the sensor, and a
/// colour key. PNG bytes.
pub fn scan_png(scene: &Scene, points: ScanPoints, sensor: Vec2, road_users: &[Box3]) -> Result<Vec<u8>> {
    type Rgb = (u8, u8, u8);
    type Key = &'static [(Rgb, &'static str)];
    let (dots, radius, key): (Vec<(Vec2, Rgb)>, f32, Key) = match points {
        ScanPoints::Lidar(points) => {
            let colour = |z: f32| {
                let h = ((z - scene.ground.z_m) / 4.0).clamp(0.0, 1.0);
                ((40.0 + 215.0 * h) as u8, (200.0 - 120.0 * h) as u8, (255.0 - 200.0 * h) as u8)
            };
            let dots = points.iter().map(|p| (Vec2::new(p.x, p.y), colour(p.z))).collect();
            (dots, 1.0, &[((40, 200, 255), "LiDAR point at the ground"), ((255, 80, 55), "4 m above it")])
        }
        ScanPoints::Radar(points) => {
            let colour = |v: f32| {
                let k = (v / 10.0).clamp(-1.0, 1.0);
                if k < 0.0 {
                    (255, (255.0 * (1.0 + k)) as u8, (255.0 * (1.0 + k)) as u8)
                } else {
                    ((255.0 * (1.0 - k)) as u8, (255.0 * (1.0 - k)) as u8, 255)
                }
            };
            let dots = points.iter().map(|p| (Vec2::new(p.x, p.y), colour(p.v_r_mps))).collect();
            let key: Key = &[
                ((255, 0, 0), "radar point approaching (10 m/s)"),
                ((255, 255, 255), "radar point static"),
                ((0, 0, 255), "radar point receding (10 m/s)"),
            ];
            (dots, 2.5, key)
        }
    };
    let mut canvas = scene_canvas(scene, 4.0)?;
    canvas.boxes(road_users, (255, 230, 0));
    canvas.dots(&dots, radius);
    canvas.dots(&[(sensor, (255, 0, 255))], 5.0);
    let mut keys = vec![((255, 0, 255), "sensor"), ((255, 230, 0), "road user (tick: heading)")];
    keys.extend_from_slice(key);
    canvas.legend(&keys);
    canvas.png()
}

pub fn scene_canvas(scene: &Scene, px_per_m: f32) -> Result<Canvas> {
    scene_canvas_within(scene, scene.ground.min, scene.ground.max, px_per_m)
}

/// The scene drawn as [`scene_canvas`] draws it, in the window from `min` to `max` (metres).
pub fn scene_canvas_within(scene: &Scene, min: Vec2, max: Vec2, px_per_m: f32) -> Result<Canvas> {
    let view = View { min, max, scale: px_per_m };
    let size = (max - min) * px_per_m;
    let pm = Pixmap::new(size.x.ceil() as u32, size.y.ceil() as u32).ok_or_else(|| StudyError::Picture {
        what: "the scene".into(),
        message: format!("{:.0}x{:.0} px is empty or too large", size.x, size.y),
    })?;
    let mut c = Canvas { pm, view };
    c.pm.fill(Color::from_rgba8(200, 211, 178, 255));

    let asphalt = paint(70, 70, 74, 255);
    for arm in &scene.layout.arms {
        c.fill(&arm.road, &asphalt);
    }
    c.fill(&scene.layout.central, &asphalt);
    let concrete = paint(214, 209, 199, 255);
    for arm in &scene.layout.arms {
        for s in &arm.sidewalks {
            c.fill(s, &concrete);
        }
        if let Some(m) = &arm.median {
            c.fill(m, &paint(176, 168, 150, 255));
        }
    }
    for s in &scene.layout.corner_sidewalks {
        c.fill(s, &concrete);
    }
    // Lane markings: dashed white between lanes of one direction, solid yellow at the median.
    let white = paint(245, 245, 245, 255);
    let yellow = paint(240, 200, 40, 255);
    for arm in &scene.layout.arms {
        for lane in &arm.lanes {
            let d = (lane.end - lane.start).normalize_or_zero();
            let side = d.perp() * (0.5 * lane.width_m);
            // Left boundary in driving direction.
            let (a, b) = (lane.start + side, lane.end + side);
            let s_left = ((a + b) * 0.5).dot(arm.normal);
            let at_median = ((s_left - arm.offset_m).abs() - arm.median_half_width_m).abs() < 1e-3;
            if at_median {
                c.stroke(&[a, b], &yellow, 0.15, None);
            } else {
                c.stroke(&[a, b], &white, 0.12, Some((3.0, 6.0)));
            }
        }
        // A parking lane: a solid white line between it and the outer lane, beyond the crosswalk.
        if arm.parking_lane_m > 0.0 {
            let (from, to) =
                (arm.crosswalk[1].dot(arm.dir).max(arm.crosswalk[0].dot(arm.dir)), arm.road[1].dot(arm.dir));
            for (edge, inward) in [(arm.edge_in_m, -1.0), (arm.edge_out_m, 1.0)] {
                let s = edge + inward * arm.parking_lane_m;
                c.stroke(&[arm.dir * from + arm.normal * s, arm.dir * to + arm.normal * s], &white, 0.12, None);
            }
        }
        c.stroke(&arm.stop_line, &white, 0.45, None);
        // Zebra crosswalk: bars parallel to the traffic, spread across the road.
        let cw = &arm.crosswalk;
        let (along, across) = (cw[1] - cw[0], cw[3] - cw[0]);
        let width = across.length();
        let mut o = 0.3;
        while o + 0.6 <= width {
            let u = across / width;
            let p0 = cw[0] + u * o;
            c.fill(&[p0, p0 + along, p0 + along + u * 0.6, p0 + u * 0.6], &white);
            o += 1.2;
        }
    }
    // ROIs, translucent, heavier weight = redder.
    let max_w = scene.rois.iter().map(|r| r.weight).fold(0.0, f32::max);
    for roi in &scene.rois {
        let k = if max_w > 0.0 { roi.weight / max_w } else { 1.0 };
        let fill = paint(230, (170.0 - 120.0 * k) as u8, 40, 70);
        let edge = paint(200, (140.0 - 110.0 * k) as u8, 20, 220);
        for poly in &roi.polygons {
            c.fill(poly, &fill);
            c.outline(poly, &edge, 2.0);
        }
    }
    // A roundabout's island, over the ROI it is a hole in.
    if let Some(ring) = &scene.layout.ring {
        let (r, g, b) = ISLAND;
        c.fill(&ring.island, &paint(r, g, b, 255));
        c.outline(&ring.island, &paint(214, 209, 199, 255), 1.5);
    }
    // Buildings and imported meshes.
    for b in &scene.config.buildings {
        let fp: Vec<Vec2> = b.footprint.iter().map(|p| Vec2::from(*p)).collect();
        c.fill(&fp, &paint(141, 110, 99, 255));
        c.outline(&fp, &paint(80, 60, 50, 255), 1.5);
    }
    for (k, tri) in scene.mesh.triangles.iter().enumerate() {
        if scene.objects[scene.mesh.object[k] as usize].kind == ObjectKind::Mesh {
            c.fill(&[tri[0].truncate(), tri[1].truncate(), tri[2].truncate()], &paint(160, 130, 100, 200));
        }
    }
    // Trees: crown and trunk.
    for t in &scene.config.trees {
        let p = Vec2::from(t.position);
        c.disc(p, t.crown_radius_m, &paint(46, 125, 50, 190));
        c.disc(p, t.trunk_radius_m.max(0.3), &paint(93, 64, 55, 255));
    }
    // Street lights and signal poles (mounting structures) with their arms and heads.
    for s in &scene.config.street_lights {
        let p = Vec2::from(s.position);
        let tip = p + Vec2::from_angle(s.arm_heading_deg.to_radians()) * s.arm_length_m;
        c.stroke(&[p, tip], &paint(120, 120, 120, 255), 0.25, None);
        c.disc(p, 0.35, &paint(90, 90, 90, 255));
    }
    for m in &scene.mounts {
        let tip = m.base + m.arm_dir * m.arm_length_m;
        c.stroke(&[m.base, tip], &paint(25, 25, 25, 255), 0.5, None);
        c.disc(m.base, 0.6, &paint(10, 10, 10, 255));
    }
    for p in &scene.config.signal_poles {
        let dir = Vec2::from_angle(p.arm_heading_deg.to_radians());
        for off in &p.head_offsets_m {
            let h = Vec2::from(p.position) + dir * *off;
            let n = dir.perp() * 0.3;
            let d = dir * 0.25;
            c.fill(&[h - d - n, h + d - n, h + d + n, h - d + n], &yellow);
        }
    }
    // Scale bar (20 m, 5 m ticks) bottom-left and a north arrow top-right.
    c.scale_bar(20.0);
    c.north_arrow();
    Ok(c)
}

/// A JSON summary of a scene for `hilo scene info`.
pub fn scene_summary(scene: &Scene) -> serde_json::Value {
    let mut kinds = std::collections::BTreeMap::<String, usize>::new();
    for (k, _) in scene.mesh.triangles.iter().enumerate() {
        let kind = scene.objects[scene.mesh.object[k] as usize].kind;
        *kinds
            .entry(serde_json::to_value(kind).map(|v| v.as_str().unwrap_or("?").to_owned()).unwrap_or_default())
            .or_default() += 1;
    }
    let rois: Vec<_> = scene
        .rois
        .iter()
        .map(|r| {
            // Area by 0.5 m sampling over the polygons' bounds (polygons may overlap).
            let pts: Vec<Vec2> = r.polygons.iter().flatten().copied().collect();
            let lo = pts.iter().fold(Vec2::splat(f32::MAX), |a, b| a.min(*b));
            let hi = pts.iter().fold(Vec2::splat(f32::MIN), |a, b| a.max(*b));
            let step = 0.5;
            let mut cells = 0usize;
            let mut y = lo.y + step / 2.0;
            while y < hi.y {
                let mut x = lo.x + step / 2.0;
                while x < hi.x {
                    let p = Vec2::new(x, y);
                    if r.polygons.iter().any(|poly| point_in_polygon(p, poly)) {
                        cells += 1;
                    }
                    x += step;
                }
                y += step;
            }
            json!({"name": r.name, "weight": r.weight, "polygons": r.polygons.len(), "area_m2": cells as f32 * step * step})
        })
        .collect();
    json!({
        "name": scene.config.name,
        "source": scene.source_name(),
        "origin": [scene.frame.origin.x, scene.frame.origin.y, scene.frame.origin.z],
        "static_triangles": scene.mesh.len(),
        "triangles_by_kind": kinds,
        "objects": scene.objects.len(),
        "arms": scene.layout.arms.iter().map(|a| json!({"name": a.name, "lanes": a.lanes.len(), "stop_line_at_m": a.stop_line_at_m})).collect::<Vec<_>>(),
        "mounting_structures": scene.mounts.iter().map(|m| json!({"name": m.name, "pole_height_m": m.pole_height_m, "arm_length_m": m.arm_length_m, "arm_height_m": m.arm_height_m})).collect::<Vec<_>>(),
        "rois": rois,
        "assumed": scene.assumed,
        "demand": demand_summary(scene),
    })
}

/// Each approach's vehicles per hour at the demand levels, under the default turning shares and
/// signal timing (a study's own `[dataset.traffic]` may differ), with the lane group that sets it.
fn demand_summary(scene: &Scene) -> serde_json::Value {
    use hilo_dataset::traffic::{Demand, TrafficConfig, demand::levels_of};
    let cfg = TrafficConfig::default();
    let level = |d: Demand| {
        let rows: Vec<_> = levels_of(&scene.layout, &cfg, d)
            .into_iter()
            .map(|a| json!({"arm": a.arm, "vehicles_per_hour": a.vehicles_per_hour.round(), "critical": a.critical}))
            .collect();
        json!({"pedestrians_per_hour": d.pedestrians_per_hour(), "approaches": rows})
    };
    json!({
        "at": "default turning shares and signal timing",
        "off_peak": level(Demand::OffPeak),
        "peak": level(Demand::Peak),
    })
}

/// Box colours, one per class in [`hilo_core::Class::ALL`] order.
const CLASS_COLOURS: [(u8, u8, u8); 7] =
    [(80, 170, 255), (255, 170, 60), (120, 230, 120), (255, 90, 200), (250, 250, 120), (160, 120, 255), (240, 70, 50)];
/// Point colours, one per sensor of the frame (greys and pastels, apart from the box colours).
const SENSOR_COLOURS: [(u8, u8, u8); 6] =
    [(210, 210, 210), (130, 220, 230), (240, 180, 180), (150, 150, 150), (200, 230, 160), (230, 200, 240)];

/// One frame of a dataset drawn from above, and how many points and boxes it holds.
#[derive(Debug)]
pub struct FramePicture {
    pub canvas: Canvas,
    pub points: usize,
    pub boxes: usize,
}

/// Frame `frame` (in sample order) of a dataset from above: each sensor's points in the world
/// frame in a colour of its own, the annotated boxes by class, a legend, a scale bar and north.
pub fn dataset_frame(ds: &hilo_dataset::Dataset, frame: usize) -> Result<FramePicture> {
    let t = &ds.tables;
    let class_of = ds.instance_classes();
    let sample = t.sample.get(frame).ok_or_else(|| StudyError::Argument {
        flag: "--frame",
        value: frame.to_string(),
        reason: format!("the dataset has {} frames", t.sample.len()),
    })?;
    let mut dots = Vec::new();
    let mut keys: Vec<((u8, u8, u8), String)> = Vec::new();
    for (k, sd) in t.sample_data.iter().filter(|s| s.sample_token == sample.token).enumerate() {
        let cs = t.calibrated_sensor.iter().find(|c| c.token == sd.calibrated_sensor_token).ok_or_else(|| {
            StudyError::Unknown {
                what: "calibrated sensor",
                name: sd.calibrated_sensor_token.clone(),
                place: format!("the dataset (sample_data {})", sd.token),
                known: "a dangling token".into(),
            }
        })?;
        let q = glam::Quat::from_xyzw(
            cs.rotation[1] as f32,
            cs.rotation[2] as f32,
            cs.rotation[3] as f32,
            cs.rotation[0] as f32,
        );
        let position = Vec3::new(cs.translation[0] as f32, cs.translation[1] as f32, cs.translation[2] as f32);
        let col = SENSOR_COLOURS[k % SENSOR_COLOURS.len()];
        let channel = t.sensor.iter().find(|x| x.token == cs.sensor_token).map_or("sensor", |x| x.channel.as_str());
        keys.push((col, format!("{channel} point")));
        let pts: Vec<Vec3> = if sd.filename.ends_with(".pcd.bin") {
            ds.lidar_points(sd)?.iter().map(|p| Vec3::new(p.x, p.y, p.z)).collect()
        } else {
            ds.radar_points(sd)?.iter().map(|p| Vec3::new(p.x, p.y, p.z)).collect()
        };
        dots.extend(pts.into_iter().map(|p| ((position + q * p).truncate(), col)));
    }
    let boxes: Vec<(Box3, (u8, u8, u8))> = t
        .sample_annotation
        .iter()
        .filter(|a| a.sample_token == sample.token)
        .map(|a| {
            let yaw = 2.0 * a.rotation[3].atan2(a.rotation[0]);
            let b = Box3::new(
                Vec3::new(a.translation[0] as f32, a.translation[1] as f32, a.translation[2] as f32),
                a.size[1] as f32,
                a.size[0] as f32,
                a.size[2] as f32,
                yaw as f32,
            );
            let c = class_of
                .get(a.instance_token.as_str())
                .and_then(|c| c.parse::<hilo_core::Class>().ok())
                .map_or(0, |c| c.index());
            (b, CLASS_COLOURS[c])
        })
        .collect();
    let all: Vec<Vec2> = dots.iter().map(|d| d.0).chain(boxes.iter().map(|b| b.0.center.truncate())).collect();
    let lo = all.iter().fold(Vec2::splat(-20.0), |a, b| a.min(*b)) - Vec2::splat(5.0);
    let hi = all.iter().fold(Vec2::splat(20.0), |a, b| a.max(*b)) + Vec2::splat(5.0);
    let scale = (1600.0 / (hi - lo).max_element()).clamp(1.0, 10.0);
    let mut canvas = blank_canvas(lo, hi, scale)?;
    canvas.dots(&dots, 1.0);
    for (b, col) in &boxes {
        canvas.boxes(std::slice::from_ref(b), *col);
    }
    // The classes the dataset's category table lists (the paper's six, and cyclists where its
    // traffic carries them).
    keys.extend(
        ds.classes().into_iter().map(|c| (CLASS_COLOURS[c.index()], format!("{} box (tick: heading)", c.name()))),
    );
    let key_refs: Vec<((u8, u8, u8), &str)> = keys.iter().map(|(c, t)| (*c, t.as_str())).collect();
    canvas.legend(&key_refs);
    canvas.scale_bar(20.0);
    canvas.north_arrow();
    Ok(FramePicture { canvas, points: dots.len(), boxes: boxes.len() })
}
