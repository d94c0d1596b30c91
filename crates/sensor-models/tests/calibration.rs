//! A rig's calibration error: the drawn true poses have the stated spread, and a seed gives
//! the same pose.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_sensor_models::noise::{rng_for, stream};
use hilo_sensor_models::{CalibrationError, SensorPose};

#[test]
fn true_poses_spread_as_the_error_says() {
    let nominal = SensorPose::new(Vec3::new(3.0, -2.0, 6.5), 0.7, 0.17, 0.0);
    let e = CalibrationError { rotation_deg: 0.2, translation_m: 0.02 };
    let n = 4000;
    let draws: Vec<SensorPose> =
        (0..n).map(|k| nominal.miscalibrated(&e, &mut rng_for(9, stream::CALIBRATION, k))).collect();
    // Each draw's six components: the position's offsets and the three angles' changes.
    let offsets = |p: &SensorPose| -> [f64; 6] {
        let d = p.position - nominal.position;
        [d.x, d.y, d.z, p.yaw - nominal.yaw, p.pitch - nominal.pitch, p.roll - nominal.roll].map(f64::from)
    };
    let r = f64::from(0.2f32.to_radians());
    let sigmas = [0.02, 0.02, 0.02, r, r, r];
    for (k, (name, sigma)) in ["x", "y", "z", "yaw", "pitch", "roll"].iter().zip(sigmas).enumerate() {
        let v: Vec<f64> = draws.iter().map(|p| offsets(p)[k]).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        // 4,000 draws: the mean within 4 standard errors, the spread within 6%.
        assert!(mean.abs() < 4.0 * sigma / (n as f64).sqrt(), "{name}: mean {mean}");
        assert!((sd / sigma - 1.0).abs() < 0.06, "{name}: sd {sd} against {sigma}");
    }
    let again = nominal.miscalibrated(&e, &mut rng_for(9, stream::CALIBRATION, 0));
    assert_eq!(again, draws[0]);
    let none =
        nominal.miscalibrated(&CalibrationError { rotation_deg: 0.0, translation_m: 0.0 }, &mut rng_for(9, 4, 0));
    assert_eq!(none, nominal);
}
