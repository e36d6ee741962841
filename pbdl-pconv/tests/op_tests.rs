//! The continuous convolution against independent scalar references, finite differences,
//! conservation and degenerate neighbourhoods.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, GradCheckOptions};
use pbdl_particles::Domain;
use pbdl_pconv::{continuous_conv, Basis, CoordinateMap, FilterSpec, PairGraph, Window};
use rand::Rng;
use std::f64::consts::PI;
use std::sync::Arc;

// ---------------------------------------------------------------------------------------------
// Scalar references, transcribed from the CConv description (Open3D's ContinuousConv), written
// without dual numbers or the crate's helpers.

/// Open3D's ball-to-cube map on a point of the unit ball (3D).
fn ref_ball_to_cube(p: [f64; 3]) -> [f64; 3] {
    let (x, y, z) = (p[0], p[1], p[2]);
    let n = (x * x + y * y + z * z).sqrt();
    if n < 1e-6 {
        return [0.0; 3];
    }
    let (cx, cy, cz) = if 1.25 * z * z > x * x + y * y {
        let f = (3.0 * n / (n + z.abs())).sqrt();
        (x * f, y * f, z.signum() * n)
    } else {
        let g = n / (x * x + y * y).sqrt();
        (x * g, y * g, 1.5 * z)
    };
    let (a, b) = ref_disc_to_square(cx, cy);
    [a, b, cz]
}

fn ref_disc_to_square(x: f64, y: f64) -> (f64, f64) {
    if x == 0.0 && y == 0.0 {
        return (0.0, 0.0);
    }
    let r = (x * x + y * y).sqrt();
    if y.abs() <= x.abs() {
        let s = x.signum() * r;
        (s, s * 4.0 / PI * (y / x).atan())
    } else {
        let s = y.signum() * r;
        (s * 4.0 / PI * (x / y).atan(), s)
    }
}

/// CConv's clamped multilinear interpolation weights of a filter grid of size `k` at the
/// coordinate `q` in `[-1, 1]^dim`, as a dense `k^dim` vector (last axis fastest).
fn ref_interpolation(q: &[f64], k: usize) -> Vec<f64> {
    let dim = q.len();
    let mut w = vec![0.0; k.pow(dim as u32)];
    let mut corner = vec![(0usize, 0usize, 0.0f64); dim];
    for a in 0..dim {
        let c = (q[a] * 0.5 + 0.5) * (k - 1) as f64;
        let i0 = (c.floor().max(0.0) as usize).min(k - 1);
        let i1 = (i0 + 1).min(k - 1);
        let t = (c - i0 as f64).clamp(0.0, 1.0);
        corner[a] = (i0, i1, t);
    }
    for bits in 0..(1usize << dim) {
        let mut idx = 0;
        let mut weight = 1.0;
        for a in 0..dim {
            let (i0, i1, t) = corner[a];
            let (i, f) = if bits >> a & 1 == 1 { (i1, t) } else { (i0, 1.0 - t) };
            idx = idx * k + i;
            weight *= f;
        }
        w[idx] += weight;
    }
    w
}

fn random_in_ball(rng: &mut impl Rng, dim: usize) -> [f64; 3] {
    loop {
        let mut p = [0.0; 3];
        for v in p.iter_mut().take(dim) {
            *v = rng.random_range(-1.0..1.0);
        }
        if p.iter().map(|v| v * v).sum::<f64>() < 1.0 {
            return p;
        }
    }
}

#[test]
fn ball_to_cube_equals_scalar_reference() {
    let mut rng = pbdl_core::seed::rng(1);
    let mut worst: f64 = 0.0;
    for _ in 0..20_000 {
        let p = random_in_ball(&mut rng, 3);
        let (q, _) = CoordinateMap::BallToCube.apply(3, p);
        let r = ref_ball_to_cube(p);
        for a in 0..3 {
            worst = worst.max((q[a] - r[a]).abs());
            assert!(q[a].abs() <= 1.0 + 1e-12, "{p:?} -> {q:?} leaves the cube");
        }
        let p2 = random_in_ball(&mut rng, 2);
        let (q2, _) = CoordinateMap::BallToCube.apply(2, p2);
        let r2 = ref_disc_to_square(p2[0], p2[1]);
        worst = worst.max((q2[0] - r2.0).abs()).max((q2[1] - r2.1).abs());
    }
    assert!(worst < 1e-6, "max deviation {worst:e}");
    // The map is volume-preserving up to the constant 8 / (4π/3): the image of uniform ball
    // samples is uniform in the cube, so each octant-split half holds half the points.
    let mut counts = [0usize; 8];
    let mut rng = pbdl_core::seed::rng(2);
    for _ in 0..40_000 {
        let (q, _) = CoordinateMap::BallToCube.apply(3, random_in_ball(&mut rng, 3));
        let cell = |v: f64| usize::from(v.abs() > 0.5);
        counts[cell(q[0]) * 4 + cell(q[1]) * 2 + cell(q[2])] += 1;
    }
    for c in counts {
        assert!((c as f64 - 5000.0).abs() < 5.0 * 5000f64.sqrt() * 1.2, "cube cells not equally filled: {counts:?}");
    }
}

#[test]
fn linear_basis_equals_cconv_interpolation() {
    let mut rng = pbdl_core::seed::rng(3);
    for dim in 1..=3 {
        for k in [2usize, 3, 4] {
            let spec = FilterSpec { window: Window::None, ..FilterSpec::cconv(dim, k, 1.0) };
            let mut eval = spec.evaluator::<f64>();
            let mut vals = vec![0.0; spec.filter_size()];
            for _ in 0..500 {
                let p = random_in_ball(&mut rng, dim);
                eval.values(&p[..dim], &mut vals);
                let (q, _) = CoordinateMap::BallToCube.apply(dim, p);
                let reference = ref_interpolation(&q[..dim], k);
                for (a, b) in vals.iter().zip(&reference) {
                    assert!((a - b).abs() < 1e-6, "dim {dim} k {k} at {p:?}: {vals:?} vs {reference:?}");
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Forward against a direct double loop.

struct Case {
    graph: Arc<PairGraph>,
    positions: Tensor,
    features: Tensor,
    weights: Tensor,
    spec: FilterSpec,
}

fn positions(n: usize, dim: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = pbdl_core::seed::rng(seed);
    (0..n).map(|_| std::array::from_fn(|a| if a < dim { rng.random_range(0.0..1.0) } else { 0.0 })).collect()
}

fn graph_for(dim: usize, radius: f64, x: &[[f64; 3]]) -> PairGraph {
    match dim {
        1 => {
            let p: Vec<[f64; 1]> = x.iter().map(|v| [v[0]]).collect();
            PairGraph::build_self(&Domain::periodic([0.0], [1.0]), radius, &p).unwrap()
        }
        2 => {
            let p: Vec<[f64; 2]> = x.iter().map(|v| [v[0], v[1]]).collect();
            PairGraph::build_self(&Domain::periodic([0.0; 2], [1.0; 2]), radius, &p).unwrap()
        }
        _ => PairGraph::build_self(&Domain::periodic([0.0; 3], [1.0; 3]), radius, x).unwrap(),
    }
}

fn case(spec: FilterSpec, n: usize, cin: usize, cout: usize, seed: u64) -> Case {
    let dim = spec.dim;
    let x = positions(n, dim, seed);
    let graph = Arc::new(graph_for(dim, spec.radius, &x));
    let dev = Device::Cpu;
    let flat: Vec<f64> = x.iter().flat_map(|p| p[..dim].to_vec()).collect();
    let positions = Tensor::from_vec(flat, (n, dim), &dev).unwrap();
    let features = pbdl_core::seed::randn((n, cin), 0.0, 1.0, DType::F64, &dev, seed + 1).unwrap();
    let weights =
        pbdl_core::seed::randn((spec.filter_size(), cin, cout), 0.0, 1.0, DType::F64, &dev, seed + 2).unwrap();
    Case { graph, positions, features, weights, spec }
}

fn reference_forward(c: &Case) -> Vec<f64> {
    let g = &c.graph;
    let spec = c.spec;
    let d = g.offsets(&c.positions, &c.positions).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let f = c.features.to_vec2::<f64>().unwrap();
    let (k, cin, cout) = c.weights.dims3().unwrap();
    let w = c.weights.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let mut eval = spec.evaluator::<f64>();
    let mut vals = vec![0.0; k];
    let mut out = vec![0.0; g.n_receivers() * cout];
    for p in 0..g.num_pairs() {
        let (i, j) = (g.receivers()[p] as usize, g.senders()[p] as usize);
        eval.values(&d[p * spec.dim..(p + 1) * spec.dim], &mut vals);
        for kk in 0..k {
            for ci in 0..cin {
                let feat = if spec.antisymmetric { f[i][ci] + f[j][ci] } else { f[j][ci] };
                for o in 0..cout {
                    out[i * cout + o] += vals[kk] * feat * w[(kk * cin + ci) * cout + o];
                }
            }
        }
    }
    out
}

fn specs() -> Vec<FilterSpec> {
    let mut v = Vec::new();
    for dim in 1..=3 {
        let r = [0.09, 0.2, 0.3][dim - 1];
        v.push(FilterSpec::cconv(dim, 4, r));
        v.push(FilterSpec::sfbc(dim, Basis::Fourier, 4, r));
        v.push(FilterSpec::sfbc(dim, Basis::Chebyshev, 3, r).antisymmetric());
        v.push(FilterSpec { window: Window::Peak, ..FilterSpec::sfbc(dim, Basis::Gaussian, 3, r) });
    }
    for b in [Basis::FourierFull, Basis::FourierEven, Basis::FourierOdd, Basis::Linear] {
        v.push(FilterSpec::sfbc(1, b, 5, 0.09));
    }
    v
}

#[test]
fn forward_equals_direct_double_loop() {
    for (s, spec) in specs().into_iter().enumerate() {
        // More than one block of receivers (64) to cover the block loop.
        let c = case(spec, 150, 3, 2, 10 + s as u64);
        assert!(c.graph.num_pairs() > 150, "{spec:?}: only {} pairs", c.graph.num_pairs());
        let out = continuous_conv(
            &c.features,
            &c.weights,
            &c.graph.offsets(&c.positions, &c.positions).unwrap(),
            &c.graph,
            &spec,
        )
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f64>()
        .unwrap();
        let reference = reference_forward(&c);
        let scale = reference.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let err = out.iter().zip(&reference).fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        assert!(err <= 1e-12 * scale, "{spec:?}: max error {err:e} of {scale:e}");
    }
}

#[test]
fn gradients_match_finite_differences() {
    let opts = GradCheckOptions { eps: 1e-6, max_probes: 24, seed: 5 };
    for (s, spec) in specs().into_iter().enumerate() {
        let c = case(spec, 90, 2, 2, 40 + s as u64);
        let graph = c.graph.clone();
        let report = check_grad(
            |xs| {
                let d = graph.offsets(&xs[2], &xs[2]).map_err(candle_core::Error::wrap)?;
                let y = continuous_conv(&xs[0], &xs[1], &d, &graph, &spec).map_err(candle_core::Error::wrap)?;
                // A smooth nonlinearity so the cotangent differs per element.
                y.tanh()
            },
            &[c.features.clone(), c.weights.clone(), c.positions.clone()],
            &opts,
        )
        .unwrap();
        assert!(report.max_rel_error < 1e-4, "{spec:?}: {report:?}");
    }
}

#[test]
fn antisymmetric_outputs_sum_to_zero() {
    for dim in 1..=3 {
        for basis in [Basis::Linear, Basis::Fourier, Basis::Chebyshev] {
            let mut spec = FilterSpec::sfbc(dim, basis, 4, [0.09, 0.2, 0.3][dim - 1]).antisymmetric();
            spec.map = CoordinateMap::BallToCube;
            spec.window = Window::Poly6;
            let c = case(spec, 200, 3, 4, 70 + dim as u64);
            let out = continuous_conv(
                &c.features,
                &c.weights,
                &c.graph.offsets(&c.positions, &c.positions).unwrap(),
                &c.graph,
                &spec,
            )
            .unwrap();
            let total = out.sum(0).unwrap().to_vec1::<f64>().unwrap();
            let scale = out.abs().unwrap().sum(0).unwrap().to_vec1::<f64>().unwrap();
            for (t, s) in total.iter().zip(&scale) {
                assert!(t.abs() <= 1e-12 * s, "dim {dim} {basis:?}: sum {t:e} of {s:e}");
            }
            // The same filter without antisymmetry does not conserve (the check can fail).
            let plain = FilterSpec { antisymmetric: false, ..spec };
            let out = continuous_conv(
                &c.features,
                &c.weights,
                &c.graph.offsets(&c.positions, &c.positions).unwrap(),
                &c.graph,
                &plain,
            )
            .unwrap();
            let total = out.sum(0).unwrap().to_vec1::<f64>().unwrap();
            let scale = out.abs().unwrap().sum(0).unwrap().to_vec1::<f64>().unwrap();
            assert!(total.iter().zip(&scale).any(|(t, s)| t.abs() > 1e-6 * s), "plain filter summed to zero too");
        }
    }
}

#[test]
fn degenerate_neighbourhoods_stay_finite() {
    let dev = Device::Cpu;
    let r = 0.1;
    // An isolated particle, two coincident particles, and one exactly on the support radius.
    let x: Vec<[f64; 2]> = vec![[0.8, 0.8], [0.3, 0.3], [0.3, 0.3], [0.3, 0.4], [0.5, 0.5]];
    let graph = Arc::new(PairGraph::build_self(&Domain::bounded([0.0; 2], [1.0; 2]), r, &x).unwrap());
    let counts = graph.neighbor_counts();
    assert_eq!(counts[0], 0, "isolated particle has neighbours");
    assert_eq!(counts[1], 1, "coincident pair: exactly the other copy; on the radius: excluded");
    for spec in [
        FilterSpec::cconv(2, 4, r),
        FilterSpec::sfbc(2, Basis::Fourier, 5, r),
        FilterSpec::cconv(2, 3, r).antisymmetric(),
    ] {
        let pos = Tensor::new(&[[0.8f64, 0.8], [0.3, 0.3], [0.3, 0.3], [0.3, 0.4], [0.5, 0.5]], &dev).unwrap();
        let pos = candle_core::Var::from_tensor(&pos).unwrap();
        let f = candle_core::Var::from_tensor(&Tensor::ones((5, 2), DType::F64, &dev).unwrap()).unwrap();
        let w = candle_core::Var::from_tensor(&Tensor::ones((spec.filter_size(), 2, 3), DType::F64, &dev).unwrap())
            .unwrap();
        let d = graph.offsets(pos.as_tensor(), pos.as_tensor()).unwrap();
        let y = continuous_conv(f.as_tensor(), w.as_tensor(), &d, &graph, &spec).unwrap();
        let vals = y.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        assert!(vals.iter().all(|v| v.is_finite()), "{spec:?}: {vals:?}");
        assert!(vals[..3].iter().all(|&v| v == 0.0), "isolated particle output {:?}", &vals[..3]);
        let grads = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        for v in [&pos, &f, &w] {
            let g = grads.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            assert!(g.iter().all(|v| v.is_finite()), "{spec:?}: non-finite gradient {g:?}");
        }
    }
    // No particles at all.
    let empty: Vec<[f64; 2]> = Vec::new();
    let graph = Arc::new(PairGraph::build_self(&Domain::bounded([0.0; 2], [1.0; 2]), r, &empty).unwrap());
    let spec = FilterSpec::cconv(2, 4, r);
    let y = continuous_conv(
        &Tensor::zeros((0, 2), DType::F32, &dev).unwrap(),
        &Tensor::zeros((16, 2, 3), DType::F32, &dev).unwrap(),
        &Tensor::zeros((0, 2), DType::F32, &dev).unwrap(),
        &graph,
        &spec,
    )
    .unwrap();
    assert_eq!(y.dims(), &[0, 3]);
}

#[test]
fn f32_agrees_with_f64() {
    let spec = FilterSpec::cconv(3, 4, 0.3);
    let c = case(spec, 300, 4, 5, 90);
    let d = c.graph.offsets(&c.positions, &c.positions).unwrap();
    let y64 = continuous_conv(&c.features, &c.weights, &d, &c.graph, &spec).unwrap();
    let to32 = |t: &Tensor| t.to_dtype(DType::F32).unwrap();
    let y32 = continuous_conv(&to32(&c.features), &to32(&c.weights), &to32(&d), &c.graph, &spec).unwrap();
    let diff = (y64 - y32.to_dtype(DType::F64).unwrap())
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f64>()
        .unwrap();
    assert!(diff < 1e-4, "f32 vs f64 max difference {diff:e}");
}

#[test]
fn bad_input_gives_typed_errors() {
    let spec = FilterSpec::cconv(2, 4, 0.2);
    let c = case(spec, 30, 2, 2, 99);
    let d = c.graph.offsets(&c.positions, &c.positions).unwrap();
    // Wrong filter size.
    let w = Tensor::zeros((9, 2, 2), DType::F64, &Device::Cpu).unwrap();
    let e = continuous_conv(&c.features, &w, &d, &c.graph, &spec).unwrap_err();
    assert!(e.to_string().contains("weights"), "{e}");
    // Radius differs from the graph's.
    let other = FilterSpec::cconv(2, 4, 0.25);
    let e = continuous_conv(&c.features, &c.weights, &d, &c.graph, &other).unwrap_err();
    assert!(e.to_string().contains("radius"), "{e}");
    // Antisymmetric on a cross graph.
    let recv = vec![[0.5, 0.5]];
    let send = vec![[0.55, 0.5], [0.45, 0.52]];
    let cross = Arc::new(PairGraph::build_cross(&Domain::bounded([0.0; 2], [1.0; 2]), 0.2, &recv, &send).unwrap());
    assert_eq!(cross.num_pairs(), 2);
    let f = Tensor::ones((2, 2), DType::F64, &Device::Cpu).unwrap();
    let d = Tensor::zeros((2, 2), DType::F64, &Device::Cpu).unwrap();
    let e = continuous_conv(&f, &c.weights, &d, &cross, &spec.antisymmetric()).unwrap_err();
    assert!(e.to_string().contains("antisymmetric"), "{e}");
    // Too few terms, NaN positions.
    assert!(FilterSpec::cconv(2, 1, 0.2).validate().unwrap_err().to_string().contains("terms"));
    let nan = vec![[f64::NAN, 0.0]];
    let e = PairGraph::build_self(&Domain::bounded([0.0; 2], [1.0; 2]), 0.2, &nan).unwrap_err();
    assert!(e.to_string().contains("not finite"), "{e}");
}
