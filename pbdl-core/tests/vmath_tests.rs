//! `pbdl_core::vmath` against libm: the error in units in the last place of the type, over a
//! dense sweep and at the edges (zero, tiny, saturation, NaN), and the slice maps against the
//! scalar functions bit for bit.

use pbdl_core::vmath;

/// Distance in ulp of `got` from the exact value `want` (computed in a wider type), measured
/// with the spacing of `f32` (`bits = 24`) or `f64` (`bits = 53`) at `want`.
fn ulps(got: f64, want: f64, bits: i32) -> f64 {
    if got == want {
        return 0.0;
    }
    let e = want.abs().max(f64::MIN_POSITIVE).log2().floor() as i32;
    // Two factors: 2^(e - bits + 1) alone underflows to 0 for the smallest f64 values.
    (got - want).abs() / (2f64.powi(e) * 2f64.powi(1 - bits))
}

/// Points from -range to range, denser near 0, plus tiny magnitudes.
fn sweep(range: f64) -> Vec<f64> {
    let mut xs: Vec<f64> = (-20_000..=20_000).map(|i| range * (i as f64 / 20_000.0).powi(3)).collect();
    for e in -30..0 {
        let t = 2f64.powi(e) * 1.37;
        xs.push(t);
        xs.push(-t);
    }
    xs
}

#[test]
fn f32_functions_within_three_ulp_of_libm() {
    type F = fn(f32) -> f32;
    type Reference = fn(f64) -> f64;
    let cases: [(&str, F, Reference, f64); 4] = [
        ("exp", vmath::exp::<f32>, f64::exp, 87.0),
        ("expm1", vmath::expm1::<f32>, f64::exp_m1, 87.0),
        ("tanh", vmath::tanh::<f32>, f64::tanh, 20.0),
        ("sigmoid", vmath::sigmoid::<f32>, |x| 1.0 / (1.0 + (-x).exp()), 80.0),
    ];
    for (name, f, reference, range) in cases {
        let worst = sweep(range)
            .into_iter()
            .map(|x| {
                let x = x as f32;
                ulps(f(x) as f64, reference(x as f64), 24)
            })
            .fold(0.0, f64::max);
        println!("{name} f32: max {worst:.2} ulp");
        assert!(worst <= 3.0, "{name} f32: {worst} ulp");
    }
}

#[test]
fn f64_functions_within_three_ulp_of_libm() {
    // libm's f64 functions are themselves within about 1 ulp; the bar leaves room for both.
    type F = fn(f64) -> f64;
    let cases: [(&str, F, F, f64); 4] = [
        ("exp", vmath::exp::<f64>, f64::exp, 700.0),
        ("expm1", vmath::expm1::<f64>, f64::exp_m1, 700.0),
        ("tanh", vmath::tanh::<f64>, f64::tanh, 30.0),
        ("sigmoid", vmath::sigmoid::<f64>, |x| 1.0 / (1.0 + (-x).exp()), 700.0),
    ];
    for (name, f, reference, range) in cases {
        let worst = sweep(range).into_iter().map(|x| ulps(f(x), reference(x), 53)).fold(0.0, f64::max);
        println!("{name} f64: max {worst:.2} ulp");
        assert!(worst <= 3.0, "{name} f64: {worst} ulp");
    }
}

#[test]
fn edges_saturate_and_nan_propagates() {
    assert_eq!(vmath::tanh(0.0f32), 0.0);
    assert_eq!(vmath::tanh(40.0f32), 1.0);
    assert_eq!(vmath::tanh(-40.0f32), -1.0);
    assert_eq!(vmath::tanh(f64::INFINITY), 1.0);
    assert_eq!(vmath::sigmoid(200.0f32), 1.0);
    assert!(vmath::sigmoid(-200.0f32) >= 0.0 && vmath::sigmoid(-200.0f32) < 2e-38);
    assert_eq!(vmath::exp(-1000.0f64), 0.0);
    assert_eq!(vmath::exp(1000.0f64), f64::INFINITY);
    assert_eq!(vmath::sigmoid(-1000.0f64), 0.0);
    assert_eq!(vmath::expm1(-1000.0f32), -1.0);
    assert_eq!(vmath::exp(100.0f32), f32::INFINITY);
    assert_eq!(vmath::expm1(100.0f32), f32::INFINITY);
    for v in [vmath::exp(f32::NAN), vmath::tanh(f32::NAN), vmath::sigmoid(f32::NAN), vmath::expm1(f32::NAN)] {
        assert!(v.is_nan());
    }
    assert!(vmath::tanh(f64::NAN).is_nan());
}

#[test]
fn slice_maps_equal_the_scalar_functions_bit_for_bit() {
    let xs: Vec<f32> = sweep(30.0).into_iter().map(|x| x as f32).collect();
    let mut t = xs.clone();
    vmath::tanh_in_place(&mut t);
    let mut s = xs.clone();
    vmath::sigmoid_in_place(&mut s);
    let mut e = xs.clone();
    vmath::exp_in_place(&mut e);
    for (i, &x) in xs.iter().enumerate() {
        assert_eq!(t[i].to_bits(), vmath::tanh(x).to_bits(), "tanh({x})");
        assert_eq!(s[i].to_bits(), vmath::sigmoid(x).to_bits(), "sigmoid({x})");
        assert_eq!(e[i].to_bits(), vmath::exp(x).to_bits(), "exp({x})");
    }
    let mut d: Vec<f64> = sweep(30.0);
    let orig = d.clone();
    vmath::tanh_in_place(&mut d);
    for (x, y) in orig.iter().zip(&d) {
        assert_eq!(y.to_bits(), vmath::tanh(*x).to_bits());
    }
}
