//! hilo's CPU convolution (im2col + matrix product, custom ops) against candle's `conv2d`:
//! values and both gradients, for every kernel, stride and padding the detectors use, on even
//! and odd sizes.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use candle_core::{Device, Tensor, Var};

fn max_rel(a: &Tensor, b: &Tensor) -> f32 {
    let d = (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
    let m = b.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
    d / m.max(1e-6)
}

#[test]
fn im2col_convolution_equals_candle_in_value_and_gradients() {
    let dev = Device::Cpu;
    for (c, co, h, w, k, stride, pad) in [
        (3, 5, 8, 8, 3, 1, 1),
        (4, 6, 9, 7, 3, 2, 1),
        (2, 3, 8, 8, 3, 2, 1),
        (5, 4, 6, 6, 1, 1, 0),
        (3, 2, 7, 5, 3, 1, 0),
        (1, 1, 1, 1, 3, 1, 1),
        (2, 2, 5, 5, 1, 2, 0),
    ] {
        let x = Var::from_tensor(&Tensor::randn(0f32, 1.0, (2, c, h, w), &dev).unwrap()).unwrap();
        let wt = Var::from_tensor(&Tensor::randn(0f32, 0.5, (co, c, k, k), &dev).unwrap()).unwrap();
        let ours = hilo_fusion::conv::conv2d(x.as_tensor(), wt.as_tensor(), stride, pad).unwrap();
        let theirs = x.as_tensor().conv2d(wt.as_tensor(), pad, stride, 1, 1).unwrap();
        assert_eq!(ours.dims(), theirs.dims(), "c{c} co{co} {h}x{w} k{k} s{stride} p{pad}");
        assert!(max_rel(&ours, &theirs) < 1e-5, "values differ: c{c} co{co} {h}x{w} k{k} s{stride} p{pad}");
        // The same upstream gradient through both.
        let g = Tensor::randn(0f32, 1.0, theirs.dims(), &dev).unwrap();
        let go = (ours * &g).unwrap().sum_all().unwrap().backward().unwrap();
        let gt = (theirs * &g).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in [("input", &x), ("weight", &wt)] {
            let (a, b) = (go.get(v.as_tensor()).unwrap(), gt.get(v.as_tensor()).unwrap());
            assert!(max_rel(a, b) < 1e-5, "{name} gradients differ: c{c} co{co} {h}x{w} k{k} s{stride} p{pad}");
        }
    }
}
