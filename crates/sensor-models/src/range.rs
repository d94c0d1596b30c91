//! The hard-target range equation through an extinguishing atmosphere, shared by the sensor
//! specs (a datasheet LiDAR's reach by reflectivity) and the weather (a sensor's reach in fog and
//! rain): the root of r² e^{2ar} = R₀², r = W(aR₀)/a, with Lambert's W.

/// The maximum range (m) of a sensor whose clear maximum range is `clear_m` under extinction
/// `a` (per metre, one way): the root of r² e^{2ar} = clear², r = W(a·clear)/a.
pub fn max_range_m(clear_m: f32, a: f32) -> f32 {
    if a <= 0.0 {
        return clear_m;
    }
    let x = f64::from(a) * f64::from(clear_m);
    (lambert_w0(x) / f64::from(a)) as f32
}

/// The principal branch W₀ of Lambert's function for x ≥ 0 (w e^w = x), by Halley's iteration
/// from a start that is within a few per cent everywhere; to machine precision.
pub fn lambert_w0(x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let mut w = if x < 3.0 { (1.0 + x).ln() * 0.8 } else { x.ln() - x.ln().ln().max(0.0) };
    for _ in 0..50 {
        let e = w.exp();
        let f = w * e - x;
        let step = f / (e * (w + 1.0) - (w + 2.0) * f / (2.0 * w + 2.0));
        w -= step;
        if step.abs() <= 1e-15 * (1.0 + w.abs()) {
            break;
        }
    }
    w
}
