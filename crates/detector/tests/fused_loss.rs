//! The fused losses ([`focal_sum`], [`weighted_l1`]) against the composites of candle's
//! operations they replace (values and gradients within 1e-5, norm-wise), their derivative
//! against central differences in f64, and their sums at one and two threads.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use candle_core::{Device, Tensor, Var};
use hilo_detector::loss::{
    Focal, centernet_focal_terms, class_weights, focal_sum, per_class_mean, sigmoid_focal_terms, weighted_l1,
};
use rand::{Rng, SeedableRng};

/// ‖a − b‖∞ ≤ tol · max(‖b‖∞, tiny): the norm-wise relative difference.
fn close(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    assert!(worst <= tol * scale, "{what}: worst difference {worst} against a scale of {scale}");
}

fn host(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

/// Logits with the hard cases mixed in (0, ±30, ±100, tiny), and heatmap targets: Gaussian
/// values in [0, 1), exact ones at some cells, zeros elsewhere.
fn case(n: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let hard = [0.0f32, 30.0, -30.0, 100.0, -100.0, 1e-7, -1e-7];
    let x =
        (0..n).map(|i| if i % 11 == 3 { hard[(i / 11) % hard.len()] } else { rng.random_range(-6.0..6.0) }).collect();
    let t = (0..n)
        .map(|i| match i % 7 {
            0 => 1.0,
            1 | 2 => rng.random_range(0.0..1.0f32).powi(2),
            _ => 0.0,
        })
        .collect();
    (x, t)
}

/// The fused focal sum equals the composite (terms summed per class, weighted) in value and
/// gradient: sparse `(N, K)` and dense `(B, K, H, W)` layouts, both focal losses, the plain and
/// the per-class weights, and the hard shapes: no rows, one element.
#[test]
fn the_fused_focal_sum_equals_the_composite() {
    let dev = Device::Cpu;
    let shapes: [&[usize]; 5] = [&[57, 6], &[2, 6, 9, 7], &[0, 6], &[1, 1], &[3000, 6]];
    for (s, dims) in shapes.iter().enumerate() {
        let n: usize = dims.iter().product();
        let k = dims[1];
        let (xv, tv) = case(n, s as u64);
        for kind in [Focal::CenterNet, Focal::Sigmoid] {
            let pos: Vec<f32> = (0..k).map(|c| (c % 3) as f32 * 2.0).collect();
            for weights in [vec![1.0 / 7.0; k], class_weights(&pos, k)] {
                let x = Var::from_vec(xv.clone(), *dims, &dev).unwrap();
                let fused = focal_sum(kind, x.as_tensor(), &tv, &weights).unwrap();
                let t = Tensor::from_slice(&tv, *dims, &dev).unwrap();
                let xr = Var::from_vec(xv.clone(), *dims, &dev).unwrap();
                let terms = match kind {
                    Focal::CenterNet => centernet_focal_terms(xr.as_tensor(), &t).unwrap(),
                    Focal::Sigmoid => sigmoid_focal_terms(xr.as_tensor(), &t).unwrap(),
                };
                // per_class_mean with these weights: the weights as per_class_mean makes them,
                // or every class alike.
                let reference = if weights[0] == 1.0 / 7.0 {
                    (terms.sum_all().unwrap() / 7.0).unwrap()
                } else {
                    per_class_mean(&terms, &pos).unwrap()
                };
                let what = format!("{kind:?} {dims:?}");
                close(&host(&fused), &host(&reference), 1e-5, &format!("{what}: value"));
                let (g, gr) = (fused.backward().unwrap(), reference.backward().unwrap());
                if n > 0 {
                    let (a, b) = (host(g.get(x.as_tensor()).unwrap()), host(gr.get(xr.as_tensor()).unwrap()));
                    close(&a, &b, 1e-5, &format!("{what}: gradient"));
                }
            }
        }
    }
}

/// Each focal term's derivative, as the fused backward pass uses it, against central
/// differences of the term in f64, across logits from −20 to 20 and targets at 0, between and
/// at 1.
#[test]
fn focal_derivatives_match_central_differences() {
    for kind in [Focal::CenterNet, Focal::Sigmoid] {
        for t in [0.0, 0.3, 0.9, 0.999, 1.0] {
            for i in 0..=80 {
                let x = -20.0 + 0.5 * i as f64 + 0.013;
                let h = 1e-6 * (1.0 + x.abs());
                let (f, d) = kind.term(x, t);
                let fd = (kind.term(x + h, t).0 - kind.term(x - h, t).0) / (2.0 * h);
                assert!(f >= 0.0 && f.is_finite(), "{kind:?} t {t} x {x}: term {f}");
                assert!((d - fd).abs() <= 1e-6 * (1.0 + d.abs()), "{kind:?} t {t} x {x}: {d} vs {fd}");
            }
            // Saturated logits stay finite.
            for x in [-1e4, 1e4] {
                let (f, d) = kind.term(x, t);
                assert!(f.is_finite() && d.is_finite(), "{kind:?} t {t} x {x}: {f}, {d}");
            }
        }
    }
}

/// The fused weighted L1 equals `Σ w·|pred − target|` from candle's operations, in value and
/// gradient (ties at zero difference included: both take +1 there), with weights that are zero
/// on most elements as the regression masks are.
#[test]
fn the_fused_weighted_l1_equals_the_composite() {
    let dev = Device::Cpu;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for dims in [vec![0usize, 10], vec![1, 10], vec![431, 10], vec![2, 10, 6, 5]] {
        let n: usize = dims.iter().product();
        let pv: Vec<f32> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
        let tv: Vec<f32> =
            pv.iter().enumerate().map(|(i, p)| if i % 5 == 0 { *p } else { rng.random_range(-3.0..3.0) }).collect();
        let wv: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { rng.random_range(0.0..2.0) } else { 0.0 }).collect();
        let p = Var::from_vec(pv.clone(), dims.as_slice(), &dev).unwrap();
        let fused = weighted_l1(p.as_tensor(), &tv, &wv).unwrap();
        let pr = Var::from_vec(pv, dims.as_slice(), &dev).unwrap();
        let t = Tensor::from_slice(&tv, dims.as_slice(), &dev).unwrap();
        let w = Tensor::from_slice(&wv, dims.as_slice(), &dev).unwrap();
        let reference = (pr.as_tensor() - &t).unwrap().abs().unwrap().mul(&w).unwrap().sum_all().unwrap();
        close(&host(&fused), &host(&reference), 1e-5, &format!("{dims:?}: value"));
        if n > 0 {
            let (g, gr) = (fused.backward().unwrap(), reference.backward().unwrap());
            let (a, b) = (host(g.get(p.as_tensor()).unwrap()), host(gr.get(pr.as_tensor()).unwrap()));
            close(&a, &b, 1e-6, &format!("{dims:?}: gradient"));
        }
    }
}

/// The fused sums are the same bits at one thread and at two: their partial sums are taken
/// over fixed chunks, not per thread.
#[test]
fn fused_losses_are_the_same_at_any_number_of_threads() {
    let dev = Device::Cpu;
    let n = 3 * 4096 + 17;
    let (xv, tv) = case(n, 9);
    let run = |threads: usize| -> (u32, Vec<u32>) {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let x = Var::from_vec(xv.clone(), n, &dev).unwrap();
            let l = (focal_sum(Focal::CenterNet, &x.reshape((n, 1)).unwrap(), &tv, &[0.5]).unwrap()
                + weighted_l1(x.as_tensor(), &tv, &vec![0.25; n]).unwrap())
            .unwrap();
            let g = l.backward().unwrap();
            let bits = host(g.get(x.as_tensor()).unwrap()).iter().map(|v| v.to_bits()).collect();
            (l.to_scalar::<f32>().unwrap().to_bits(), bits)
        })
    };
    assert_eq!(run(1), run(2));
}

/// Mismatched targets or weights are refused with the sizes named, not read out of bounds.
#[test]
fn mismatched_targets_are_refused() {
    let x = Tensor::zeros((4, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    let e = focal_sum(Focal::CenterNet, &x, &[0.0; 11], &[1.0; 3]).unwrap_err().to_string();
    assert!(e.contains("11 targets"), "{e}");
    let e = focal_sum(Focal::CenterNet, &x, &[0.0; 12], &[1.0; 2]).unwrap_err().to_string();
    assert!(e.contains("2 class weights"), "{e}");
    let e = weighted_l1(&x, &[0.0; 12], &[1.0; 5]).unwrap_err().to_string();
    assert!(e.contains("5 weights"), "{e}");
}
