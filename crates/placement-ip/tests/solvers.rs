//! Solvers against the exhaustive oracle, greedy against the optimum, and the IP's numerics.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_placement_ip::exact::exact_counts;
use hilo_placement_ip::exhaustive::exhaustive;
use hilo_placement_ip::greedy::greedy;
use hilo_placement_ip::instance::{coverage_coef, evaluate};
use hilo_placement_ip::mip::{Formulation, build, solve};
use hilo_placement_ip::{Instance, Limit, Modality, SensorOption, SensorType};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn types() -> Vec<SensorType> {
    vec![
        SensorType { name: "lidar-a".into(), modality: Modality::Lidar, price_usd: 4000.0 },
        SensorType { name: "lidar-b".into(), modality: Modality::Lidar, price_usd: 11000.0 },
        SensorType { name: "radar".into(), modality: Modality::Radar, price_usd: 2000.0 },
    ]
}

/// A random small instance: sparse visibility with a mix of weak and strong entries, shared
/// mounts, and targets only one modality sees.
fn random_instance(seed: u64) -> Instance {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n_t = rng.random_range(12..30);
    let weights = (0..n_t).map(|_| if rng.random_bool(0.3) { 3.0 } else { 1.0 }).collect();
    let mut options = Vec::new();
    for ty in [0usize, 1, 2] {
        for k in 0..rng.random_range(3..6) {
            let mut row = Vec::new();
            for j in 0..n_t as u32 {
                if rng.random_bool(0.5) {
                    let v = if rng.random_bool(0.5) { rng.random_range(0.6..1.0) } else { rng.random_range(0.01..0.6) };
                    row.push((j, v));
                }
            }
            options.push(SensorOption {
                ty,
                candidate: options.len() as u32,
                mount: (k % 4) as u32 + 10 * (ty == 2) as u32 * (k % 2) as u32,
                row,
            });
        }
    }
    Instance {
        weights,
        types: types(),
        options,
        p_min: 1.0 - (-1.0f64).exp(),
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    }
}

#[test]
fn ip_and_exact_search_equal_exhaustive_and_beat_greedy_on_random_instances() {
    let limits = [Limit::Counts(vec![2, 0, 1]), Limit::Counts(vec![1, 1, 1]), Limit::Counts(vec![0, 1, 1])];
    let mut checked = 0;
    let mut strictly_better = 0;
    for seed in 0..24u64 {
        let inst = random_instance(seed);
        let limit = &limits[seed as usize % 3];
        let oracle = exhaustive(&inst, limit, 10_000_000).unwrap();
        let g = greedy(&inst, limit);
        let Limit::Counts(c) = limit else { unreachable!() };
        let (e, _) = exact_counts(&inst, c, &g.selection, None).unwrap();
        let cbc = solve(&inst, limit, Formulation::Strengthened, 30.0, None).unwrap();
        let plain = solve(&inst, limit, Formulation::Plain, 30.0, None).unwrap();
        for (name, o) in [("exact", &e), ("cbc strengthened", &cbc), ("cbc plain", &plain)] {
            assert!(o.proven_optimal, "seed {seed}: {name} not proven");
            assert!(
                (o.objective - oracle.objective).abs() < 1e-6 * oracle.objective.max(1.0),
                "seed {seed}: {name} {} vs exhaustive {}",
                o.objective,
                oracle.objective
            );
            assert!(inst.check(limit, &o.selection).is_ok());
        }
        // CBC's own objective value is the exact objective of its selection.
        assert!(
            (cbc.bound - oracle.objective).abs() < 1e-4 * oracle.objective.max(1.0),
            "seed {seed}: bound {} vs {}",
            cbc.bound,
            oracle.objective
        );
        assert!(g.objective <= oracle.objective + 1e-9);
        strictly_better += (g.objective < oracle.objective - 1e-9) as usize;
        checked += 1;
    }
    assert!(checked >= 20);
    eprintln!("greedy strictly worse on {strictly_better} of {checked}");
}

/// Radar R sees all three targets. LiDAR A sees all three weakly (but enough on its own), B and
/// C see two each strongly. Greedy takes R, then A (the best single gain), then B: 6.63. The
/// optimum is R + B + C: 6.66.
#[test]
fn greedy_is_strictly_worse_on_a_constructed_instance() {
    let opt = |ty, mount, row: Vec<(u32, f32)>| SensorOption { ty, candidate: mount, mount, row };
    let inst = Instance {
        weights: vec![1.0; 3],
        types: types(),
        options: vec![
            opt(2, 0, vec![(0, 0.9), (1, 0.9), (2, 0.9)]),
            opt(0, 1, vec![(0, 0.65), (1, 0.65), (2, 0.65)]),
            opt(0, 2, vec![(0, 0.99), (1, 0.99)]),
            opt(0, 3, vec![(0, 0.99), (2, 0.99)]),
        ],
        p_min: 1.0 - (-1.0f64).exp(),
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    let limit = Limit::Counts(vec![2, 0, 1]);
    let g = greedy(&inst, &limit);
    let best = exhaustive(&inst, &limit, 1000).unwrap();
    assert_eq!(best.selection, vec![0, 2, 3]);
    assert!((best.objective - 6.66).abs() < 1e-5, "{}", best.objective);
    assert!((g.objective - 6.63).abs() < 1e-5, "{}", g.objective);
    let (e, _) = exact_counts(&inst, &[2, 0, 1], &g.selection, None).unwrap();
    assert_eq!(e.selection, vec![0, 2, 3]);
}

#[test]
fn coefficients_are_finite_at_v_one_zero_and_tiny() {
    for v in [1.0, 0.0, 1e-12, 1e-300, 0.999_999_999_999_9] {
        let a = coverage_coef(v);
        assert!(a.is_finite() && a >= 0.0, "V = {v}: {a}");
    }
    assert_eq!(coverage_coef(0.0), 0.0);
    assert!((coverage_coef(1e-12) - 1e-12).abs() < 1e-20, "ln1p keeps tiny V exact");
    assert!(coverage_coef(1.0) > 27.0 && coverage_coef(1.0) < 28.0);
    // An instance with V = 1 and V = 1e-12 builds and solves.
    let inst = Instance {
        weights: vec![1.0, 1.0],
        types: types(),
        options: vec![
            SensorOption { ty: 0, candidate: 0, mount: 0, row: vec![(0, 1.0), (1, 1e-12)] },
            SensorOption { ty: 2, candidate: 1, mount: 1, row: vec![(0, 1.0), (1, 1.0)] },
        ],
        p_min: 1.0 - (-1.0f64).exp(),
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    let o = solve(&inst, &Limit::Counts(vec![1, 0, 1]), Formulation::Plain, 10.0, None).unwrap();
    assert!((o.objective - 2.0).abs() < 1e-9, "{}", o.objective);
}

#[test]
fn a_target_seen_by_one_modality_never_counts() {
    // Target 0: LiDAR only. Target 1: radar only. Target 2: both.
    let inst = Instance {
        weights: vec![5.0, 5.0, 1.0],
        types: types(),
        options: vec![
            SensorOption { ty: 0, candidate: 0, mount: 0, row: vec![(0, 1.0), (2, 0.9)] },
            SensorOption { ty: 2, candidate: 1, mount: 1, row: vec![(1, 1.0), (2, 0.9)] },
        ],
        p_min: 0.5,
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    let sel = [0usize, 1];
    assert!((evaluate(&inst, &sel) - 1.8).abs() < 1e-6);
    let limit = Limit::Counts(vec![1, 0, 1]);
    for form in [Formulation::Plain, Formulation::Strengthened] {
        let o = solve(&inst, &limit, form, 10.0, None).unwrap();
        assert!((o.objective - 1.8).abs() < 1e-6 && (o.bound - 1.8).abs() < 1e-4, "{form:?}: {o:?}");
    }
    // In the strengthened model those targets have no t variable at all.
    let m = build(&inst, &limit, Formulation::Strengthened).unwrap();
    assert_eq!(m.t.iter().map(|(j, _)| *j).collect::<Vec<_>>(), vec![2]);
}

#[test]
fn infeasible_and_bad_inputs_are_errors() {
    let inst = random_instance(1);
    let e = exhaustive(&inst, &Limit::Budget { usd: 100.0, min: vec![1, 0, 1], max: vec![] }, 1000).unwrap_err();
    assert!(e.to_string().contains("infeasible"), "{e}");
    let e = hilo_placement_ip::exact::exact_budget(&inst, 100.0, &[1, 0, 1], &[], &[], None).unwrap_err();
    assert!(e.to_string().contains("budget"), "{e}");
    let mut bad = random_instance(2);
    bad.options[0].row.push((999, 0.5));
    assert!(bad.validate().unwrap_err().to_string().contains("999"));
    let mut bad = random_instance(2);
    bad.p_min = 1.0;
    assert!(bad.validate().is_err());
    // All-zero visibility: nothing can be covered; solvers return objective 0, no panic.
    let mut zero = random_instance(3);
    for o in &mut zero.options {
        o.row.clear();
    }
    let limit = Limit::Counts(vec![2, 0, 1]);
    assert_eq!(exhaustive(&zero, &limit, 100_000).unwrap().objective, 0.0);
    assert_eq!(solve(&zero, &limit, Formulation::Strengthened, 5.0, None).unwrap().objective, 0.0);
    let g = greedy(&zero, &limit);
    assert_eq!(exact_counts(&zero, &[2, 0, 1], &g.selection, None).unwrap().0.objective, 0.0);
}

#[test]
fn both_count_vector_bounds_are_upper_bounds_and_the_separable_one_is_tighter() {
    use hilo_placement_ip::exact::{counts_upper_bound, separable_upper_bound, top_visibilities};
    for seed in 0..20u64 {
        let inst = random_instance(seed);
        let tops = top_visibilities(&inst, 4);
        for counts in [vec![2, 0, 1], vec![1, 1, 1], vec![1, 0, 2], vec![2, 1, 2]] {
            let opt = exhaustive(&inst, &Limit::Counts(counts.clone()), 10_000_000).unwrap().objective;
            let (per_target, separable) =
                (counts_upper_bound(&inst, &counts, &tops), separable_upper_bound(&inst, &counts, &tops));
            assert!(
                opt <= separable + 1e-9 && opt <= per_target + 1e-9,
                "seed {seed} {counts:?}: {opt} > {separable} or {per_target}"
            );
            assert!(separable <= per_target + 1e-9, "seed {seed} {counts:?}: {separable} > {per_target}");
        }
    }
}

#[test]
fn lidar_first_search_equals_exhaustive_with_several_radars() {
    use hilo_placement_ip::exact::exact_lidar_first;
    for seed in 0..16u64 {
        let inst = random_instance(seed);
        for counts in [vec![1, 0, 2], vec![2, 0, 2], vec![0, 2, 3]] {
            let limit = Limit::Counts(counts.clone());
            let oracle = exhaustive(&inst, &limit, 10_000_000).unwrap();
            let g = greedy(&inst, &limit);
            let (o, proven) = exact_lidar_first(&inst, &counts, &g.selection, 10_000_000, None).unwrap();
            assert!(proven);
            assert!(
                (o.objective - oracle.objective).abs() < 1e-9 * oracle.objective.max(1.0),
                "seed {seed} {counts:?}: {} vs {}",
                o.objective,
                oracle.objective
            );
            assert!(inst.check(&limit, &o.selection).is_ok());
        }
    }
}

#[test]
fn a_deadline_returns_a_valid_bound_and_a_feasible_selection() {
    use hilo_placement_ip::exact::{exact_budget, exact_lidar_first};
    let now = Some(std::time::Instant::now());
    let mut cut_short = 0;
    for seed in 0..12u64 {
        let inst = random_instance(seed);
        for (counts, search) in [(vec![2, 0, 1], 0), (vec![2, 0, 2], 1)] {
            let limit = Limit::Counts(counts.clone());
            let oracle = exhaustive(&inst, &limit, 10_000_000).unwrap().objective;
            let g = greedy(&inst, &limit);
            let o = if search == 0 {
                exact_counts(&inst, &counts, &g.selection, now).unwrap().0
            } else {
                exact_lidar_first(&inst, &counts, &g.selection, 10_000_000, now).unwrap().0
            };
            assert!(inst.check(&limit, &o.selection).is_ok());
            assert!(o.objective >= g.objective - 1e-9 && o.objective <= oracle + 1e-9);
            assert!(o.bound >= oracle - 1e-9, "seed {seed} {counts:?}: bound {} below the optimum {oracle}", o.bound);
            assert!(o.bound.is_finite(), "seed {seed} {counts:?}: a stopped search still gives a finite bound");
            if o.proven_optimal {
                assert!((o.objective - oracle).abs() < 1e-9);
            } else {
                cut_short += 1;
            }
        }
        let b = exact_budget(&inst, 10_000.0, &[], &[], &[], now).unwrap().0;
        let full = exact_budget(&inst, 10_000.0, &[], &[], &[], None).unwrap().0;
        assert!(b.bound >= full.objective - 1e-9 && b.objective <= full.objective + 1e-9);
    }
    // Where greedy is not optimal, a search with no time left cannot have proven anything.
    assert!(cut_short > 0);
}

/// A budget where the most sensors is a sum over types, not the most of one type: radars at
/// $50 (at most 2), LiDARs at $100, $300 buys 2 radars + 2 LiDARs. Every sensor sees the one
/// target, so the optimum takes all four; a per-target bound from the largest single-type count
/// (3 sensors) would cut it off in the strengthened model.
#[test]
fn the_budget_bound_on_sensors_is_a_sum_over_types() {
    let opt = |ty, mount: u32| SensorOption { ty, candidate: mount, mount, row: vec![(0, 0.9)] };
    let inst = Instance {
        weights: vec![1.0],
        types: vec![
            SensorType { name: "lidar".into(), modality: Modality::Lidar, price_usd: 100.0 },
            SensorType { name: "radar".into(), modality: Modality::Radar, price_usd: 50.0 },
        ],
        options: vec![opt(0, 0), opt(0, 1), opt(0, 2), opt(1, 3), opt(1, 4), opt(1, 5)],
        p_min: 1.0 - (-1.0f64).exp(),
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    let limit = Limit::Budget { usd: 300.0, min: vec![], max: vec![u32::MAX, 2] };
    let oracle = exhaustive(&inst, &limit, 1000).unwrap();
    assert!((oracle.objective - 3.6).abs() < 1e-5, "{}", oracle.objective);
    for form in [Formulation::Strengthened, Formulation::Plain] {
        let cbc = solve(&inst, &limit, form, 30.0, None).unwrap();
        assert!(cbc.proven_optimal);
        assert!((cbc.objective - oracle.objective).abs() < 1e-5, "{form:?}: {} vs {}", cbc.objective, oracle.objective);
    }
    // A free sensor type is legal: bounded by its options, not by the money.
    let mut free = inst.clone();
    free.types[1].price_usd = 0.0;
    let limit = Limit::Budget { usd: 100.0, min: vec![], max: vec![] };
    let oracle = exhaustive(&free, &limit, 1000).unwrap();
    let cbc = solve(&free, &limit, Formulation::Strengthened, 30.0, None).unwrap();
    assert!((oracle.objective - 3.6).abs() < 1e-5 && (cbc.objective - oracle.objective).abs() < 1e-5);
}

/// The exact search's count vectors under a budget with a free type: as many free sensors as
/// the type has options, and the optimum equals the exhaustive one.
#[test]
fn a_free_sensor_type_is_bounded_by_its_options_in_the_exact_search() {
    use hilo_placement_ip::exact::maximal_count_vectors;
    let mut inst = random_instance(3);
    inst.types[2].price_usd = 0.0;
    let radars = inst.options.iter().filter(|o| o.ty == 2).count() as u32;
    let vectors = maximal_count_vectors(&inst, 8000.0, &[], &[]);
    assert!(!vectors.is_empty() && vectors.iter().all(|v| v[2] == radars), "{vectors:?}");
}

/// Placement given fixed sensors: it keeps them, and its objective is the best of every
/// feasible selection that holds them (every subset of the options enumerated), proven, by the
/// completions' enumeration under fixed counts and by CBC under a total; an
/// infeasible given set (two options on one mount, more of a type than the limit) is refused.
#[test]
fn a_placement_given_fixed_sensors_keeps_them_and_is_optimal_for_the_rest() {
    use hilo_placement_ip::pipeline::solve_given;
    let limits = [Limit::Counts(vec![2, 0, 1]), Limit::Counts(vec![1, 1, 2]), Limit::Total(3)];
    let mut checked = 0;
    for seed in 0..12u64 {
        let inst = random_instance(100 + seed);
        let limit = &limits[seed as usize % 3];
        // A LiDAR given (the first option of the first LiDAR type the limit allows).
        let lidar = (0..inst.options.len()).find(|&o| inst.options[o].ty == usize::from(seed % 3 == 1)).unwrap();
        let fixed = [lidar];
        let n = inst.options.len();
        assert!(n <= 18, "enumeration too large: {n} options");
        let mut best = f64::NEG_INFINITY;
        for mask in 0u32..(1 << n) {
            let sel: Vec<usize> = (0..n).filter(|&o| mask & (1 << o) != 0).collect();
            if sel.contains(&lidar) && inst.check(limit, &sel).is_ok() {
                best = best.max(evaluate(&inst, &sel));
            }
        }
        let out = solve_given(&inst, limit, &fixed, 30.0).unwrap();
        assert!(out.selection.contains(&lidar), "seed {seed}: the given sensor was dropped");
        assert!(inst.check(limit, &out.selection).is_ok());
        assert!(out.proven_optimal, "seed {seed}");
        // Fixed counts: every completion evaluated; a total: CBC with the sensor held at 1.
        let path = if matches!(limit, Limit::Counts(_)) { "every completion" } else { "CBC" };
        assert!(out.method.contains(path), "seed {seed}: {}", out.method);
        assert!((out.objective - best).abs() < 1e-6 * best.abs().max(1.0), "seed {seed}: {} vs {best}", out.objective);
        // Never better than the free optimum.
        assert!(out.objective <= exhaustive(&inst, limit, 10_000_000).unwrap().objective + 1e-9);
        checked += 1;
    }
    assert_eq!(checked, 12);
    let inst = random_instance(7);
    let same_mount: Vec<usize> = {
        let m = inst.options[0].mount;
        (0..inst.options.len()).filter(|&o| inst.options[o].mount == m).take(2).collect()
    };
    assert_eq!(same_mount.len(), 2);
    let e = solve_given(&inst, &Limit::Counts(vec![3, 3, 3]), &same_mount, 5.0).unwrap_err().to_string();
    assert!(e.contains("the given sensors") && e.contains("mount"), "{e}");
    let lidars: Vec<usize> = (0..inst.options.len()).filter(|&o| inst.options[o].ty == 0).take(2).collect();
    let e = solve_given(&inst, &Limit::Counts(vec![1, 0, 1]), &lidars, 5.0).unwrap_err().to_string();
    assert!(e.contains("exceeds"), "{e}");
}

/// A larger random instance (many options, overlapping views) that CBC cannot close at its root.
fn large_instance(seed: u64) -> Instance {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n_t = 50;
    let weights = (0..n_t).map(|_| rng.random_range(0.5..3.0)).collect();
    let mut options = Vec::new();
    for ty in [0usize, 2] {
        for k in 0..10u32 {
            let mut row = Vec::new();
            for j in 0..n_t as u32 {
                if rng.random_bool(0.3) {
                    row.push((j, rng.random_range(0.05f32..0.95)));
                }
            }
            options.push(SensorOption { ty, candidate: options.len() as u32, mount: k + 100 * ty as u32, row });
        }
    }
    Instance { weights, types: types(), options, ..random_instance(seed) }
}

/// A solve the node limit stops gives the same selection every time, says so in its method,
/// keeps the limit, is no worse than its warm start, and its bound holds the optimum.
#[test]
fn a_node_limit_stops_cbc_the_same_way_every_time() {
    use hilo_placement_ip::mip::SolveLimit;
    let limit = Limit::Counts(vec![3, 0, 2]);
    let mut stopped = 0;
    for seed in 0..3u64 {
        let inst = large_instance(seed);
        let g = greedy(&inst, &limit);
        let at = SolveLimit { seconds: 600.0, nodes: Some(1) };
        let a = solve(&inst, &limit, Formulation::Strengthened, at, Some(&g.selection)).unwrap();
        let b = solve(&inst, &limit, Formulation::Strengthened, at, Some(&g.selection)).unwrap();
        assert_eq!(a.selection, b.selection, "seed {seed}");
        assert_eq!(a.objective.to_bits(), b.objective.to_bits());
        assert!(inst.check(&limit, &a.selection).is_ok());
        assert!(a.objective >= g.objective - 1e-9);
        let full = solve(&inst, &limit, Formulation::Strengthened, 600.0, Some(&g.selection)).unwrap();
        assert!(full.proven_optimal, "seed {seed}: {}", full.method);
        assert!(a.objective <= full.objective + 1e-9 && a.bound >= full.objective - 1e-6);
        if !a.proven_optimal {
            assert!(a.method.contains("node limit (1)"), "{}", a.method);
            stopped += 1;
        }
    }
    // The instances are hard enough that one node does not close them all.
    assert!(stopped > 0);
}
