//! Pins the exact evaluation losses and step counts of `run_curve` (HIG, Adam, and a run that
//! diverges), so that moving its frame onto `pbdl_core::train::TrainLoop` changes no number.
//! The values were recorded from the loop before the move (commit c5f1131).
//!
//! The HIG curves (f64, faer) are compared bit for bit. The Adam curve runs through candle's CPU
//! ops, which are not bit-reproducible run to run on 2 threads (seen: evaluation losses 2 ulp
//! apart in 4 of 6 runs, with and without `PBDL_THREADS=1`, before and after the move), so it
//! is compared to 1e-12 relative.

use pbdl_optim::hig::{run_curve, Budget, Curve, HigConfig, Method};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Oscillators};

/// Steps of each evaluation, f64 bits of each evaluation loss, divergence step, timed steps.
type Fingerprint = (Vec<u64>, Vec<u64>, Option<u64>, usize);

fn fingerprint(c: &Curve) -> Fingerprint {
    (c.steps.clone(), c.loss.iter().map(|l| l.to_bits()).collect(), c.diverged_at, c.step_seconds.len())
}

fn curves() -> Vec<Curve> {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(512, 4, 42);
    let eval = Dataset::return_to_start(128, 4, 43);
    let net0 = Mlp::new(&[4, 12, 24], Activation::Tanh, 7).unwrap();
    let steps = |n| Budget { seconds: f64::INFINITY, max_steps: n };
    let mut out = Vec::new();
    for (method, batch, budget, every) in [
        (Method::Hig(HigConfig::hig(1.0, 1e-10)), 32, steps(20), 5),
        (Method::Adam { lr: 1e-2 }, 64, steps(20), 7),
        (Method::Hig(HigConfig::hig(1e6, 1e-12)), 32, steps(30), 3),
    ] {
        let mut net = net0.clone();
        out.push(run_curve(&mut net, &physics, method, &data, &eval, batch, budget, every).unwrap());
    }
    out
}

#[test]
fn run_curve_numbers_are_pinned() {
    let expected: [Fingerprint; 3] = [
        (
            vec![0, 5, 10, 15, 20],
            vec![
                4608427299486692116,
                4599675288275335292,
                4593276308931636539,
                4587187369780430007,
                4581629568880862614,
            ],
            None,
            20,
        ),
        (
            vec![0, 7, 14, 20],
            vec![4608427299486692116, 4602436170251074239, 4598807041038933781, 4596512536920525297],
            None,
            20,
        ),
        (
            vec![0, 3, 6, 9, 12, 15, 18, 21, 24, 27],
            vec![
                4608427299486692116,
                5094375820599039915,
                5544859818312051220,
                6028632812581318669,
                6511162274900050858,
                6998244575340402614,
                7467392031032513857,
                7931291293679932280,
                8411111234802910285,
                8897821508945988161,
            ],
            Some(29),
            29,
        ),
    ];
    for (i, (c, want)) in curves().iter().zip(expected).enumerate() {
        let got = fingerprint(c);
        if i == 1 {
            // Adam (candle): steps exact, losses to 1e-12 relative.
            assert_eq!((&got.0, got.2, got.3), (&want.0, want.2, want.3));
            for (g, w) in got.1.iter().zip(&want.1) {
                let (g, w) = (f64::from_bits(*g), f64::from_bits(*w));
                assert!((g - w).abs() <= 1e-12 * w.abs(), "Adam curve: {g} vs {w}");
            }
        } else {
            assert_eq!(got, want);
        }
    }
}
