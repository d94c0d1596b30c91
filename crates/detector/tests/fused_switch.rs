//! The process-wide switch of the fused layers (`hilo bench train --variant fused=off`): off,
//! the losses are candle's composites and give what the fused nodes give. One test, alone in
//! its binary, because the switch is process-wide.

#![allow(clippy::unwrap_used)]

use candle_core::{Device, Var};
use hilo_detector::loss::{Focal, focal_sum, weighted_l1};

fn value_and_gradient(x: &[f32], t: &[f32], dims: (usize, usize)) -> (f32, Vec<f32>) {
    let v = Var::from_vec(x.to_vec(), dims, &Device::Cpu).unwrap();
    let w: Vec<f32> = (0..x.len()).map(|i| (i % 4) as f32 * 0.5).collect();
    let l = (focal_sum(Focal::Sigmoid, v.as_tensor(), t, &[0.2, 0.3, 0.5]).unwrap()
        + weighted_l1(v.as_tensor(), t, &w).unwrap())
    .unwrap();
    let g = l.backward().unwrap();
    (l.to_scalar().unwrap(), g.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1().unwrap())
}

#[test]
fn the_fused_layers_switch_off_to_the_composites() {
    let dims = (40, 3);
    let x: Vec<f32> = (0..120).map(|i| ((i * 37 % 101) as f32 - 50.0) / 9.0).collect();
    let t: Vec<f32> = (0..120).map(|i| if i % 9 == 0 { 1.0 } else { 0.0 }).collect();
    assert_eq!(hilo_detector::cpu::fused_layers(), hilo_detector::cpu::Layer::ALL, "on by default");
    let on = value_and_gradient(&x, &t, dims);
    hilo_detector::cpu::set_fused(&[hilo_detector::cpu::Layer::Conv, hilo_detector::cpu::Layer::BnRelu]);
    let off = value_and_gradient(&x, &t, dims);
    hilo_detector::cpu::set_fused(&hilo_detector::cpu::Layer::ALL);
    assert!((on.0 - off.0).abs() <= 1e-5 * off.0.abs(), "{} vs {}", on.0, off.0);
    let scale = off.1.iter().fold(0f32, |m, v| m.max(v.abs()));
    let worst = on.1.iter().zip(&off.1).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(worst <= 1e-5 * scale, "gradients differ by {worst} (scale {scale})");
}
