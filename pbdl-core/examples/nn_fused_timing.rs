//! Fused against composed `group_norm` (one group, per-channel weight and bias) and `gelu_erf`
//! at the sizes of the ACDM U-Net, forward alone and forward + backward, `f32` on the CPU.
//! The two versions alternate call by call; the median wall time and the mean CPU time (all
//! threads; /proc counts 10 ms ticks, so only the mean over many calls means anything) are
//! printed with their ratios.
//!
//! `cargo run --release -p pbdl-core --example nn_fused_timing -- [reps]` (default 30);
//! `CASE=gelu` keeps the cases whose name contains `gelu`.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::nn::{self, activation};
use std::time::Instant;

type Case<'a> = Box<dyn Fn() -> Tensor + 'a>;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// CPU seconds (user + system) of this process so far, all threads, from /proc (Linux; NaN
/// elsewhere); steadier than wall time on a loaded machine. Ticks are 10 ms, so compare
/// means over many calls.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which ends in ')'): utime and stime are fields 14 and 15.
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let field = |i: usize| fields.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (field(11) + field(12)) / 100.0 // clock ticks at USER_HZ = 100
}

/// Wall times and CPU times of one side.
#[derive(Default)]
struct Times {
    wall: Vec<f64>,
    cpu: Vec<f64>,
}

impl Times {
    fn time(&mut self, f: &Case) {
        let (t, c) = (Instant::now(), cpu_seconds());
        std::hint::black_box(f());
        self.wall.push(t.elapsed().as_secs_f64());
        self.cpu.push(cpu_seconds() - c);
    }
    fn summary(self) -> (f64, f64) {
        let n = self.cpu.len().max(1) as f64;
        (median(self.wall), self.cpu.iter().sum::<f64>() / n)
    }
}

/// Alternates `a` and `b` for `reps` rounds after a warm-up; returns their (median wall, mean CPU) seconds.
fn ab(reps: usize, a: &Case, b: &Case) -> ((f64, f64), (f64, f64)) {
    std::hint::black_box((a(), b()));
    let (mut ta, mut tb) = (Times::default(), Times::default());
    for _ in 0..reps {
        ta.time(a);
        tb.time(b);
    }
    (ta.summary(), tb.summary())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let reps = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(30);
    let dev = Device::Cpu;
    println!("{} threads, median wall / mean CPU of {reps} alternating calls, f32", rayon::current_num_threads());
    println!(
        "{:<50} {:>8} {:>8} {:>6} | {:>8} {:>8} {:>6}",
        "case (ms; ratio = composed / fused)", "wall fus", "wall com", "ratio", "cpu fus", "cpu com", "ratio"
    );
    for shape in [[16usize, 16, 64, 32], [16, 32, 32, 16]] {
        let c = shape[1];
        let x = Var::from_tensor(&pbdl_core::seed::randn(&shape[..], 0.3, 1.2, DType::F32, &dev, 1)?)?;
        let w = Var::from_tensor(&pbdl_core::seed::randn(c, 1.0, 0.2, DType::F32, &dev, 2)?)?;
        let b = Var::from_tensor(&pbdl_core::seed::randn(c, 0.0, 0.2, DType::F32, &dev, 3)?)?;
        // A dense cotangent, as a following conv's backward would give.
        let r = pbdl_core::seed::randn(&shape[..], 0.0, 1.0, DType::F32, &dev, 4)?;
        let (xt, wt, bt) = (x.as_tensor(), w.as_tensor(), b.as_tensor());
        let xc = xt.detach();
        let back = |y: Tensor| -> Tensor {
            let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            g.get(xt).unwrap().clone()
        };
        let cases: [(&str, Case, Case); 6] = [
            (
                "group_norm fwd",
                Box::new(|| nn::group_norm(xt, 1, Some(wt), Some(bt), 1e-5).unwrap()),
                Box::new(|| nn::group_norm_composed(xt, 1, Some(wt), Some(bt), 1e-5).unwrap()),
            ),
            (
                "group_norm fwd+bwd",
                Box::new(|| back(nn::group_norm(xt, 1, Some(wt), Some(bt), 1e-5).unwrap())),
                Box::new(|| back(nn::group_norm_composed(xt, 1, Some(wt), Some(bt), 1e-5).unwrap())),
            ),
            (
                "gelu_erf fwd",
                Box::new(|| activation::gelu_erf(xt).unwrap()),
                Box::new(|| activation::gelu_erf_composed(xt).unwrap()),
            ),
            (
                "gelu_erf fwd, untracked input",
                Box::new(|| activation::gelu_erf(&xc).unwrap()),
                Box::new(|| activation::gelu_erf_composed(&xc).unwrap()),
            ),
            (
                "gelu_erf fwd+bwd",
                Box::new(|| back(activation::gelu_erf(xt).unwrap())),
                Box::new(|| back(activation::gelu_erf_composed(xt).unwrap())),
            ),
            // What both fwd+bwd rows include besides the op: y * r, sum, and its backward.
            ("loss only (x * r, sum, backward)", Box::new(|| back(xt.clone())), Box::new(|| back(xt.clone()))),
        ];
        let only = std::env::var("CASE").unwrap_or_default();
        for (name, fused, composed) in cases.iter().filter(|c| c.0.contains(only.as_str())) {
            let ((wf, cf), (wc, cc)) = ab(reps, fused, composed);
            println!(
                "{:<50} {:>8.2} {:>8.2} {:>6.2} | {:>8.2} {:>8.2} {:>6.2}",
                format!("{name} {shape:?}"),
                wf * 1e3,
                wc * 1e3,
                wc / wf,
                cf * 1e3,
                cc * 1e3,
                cc / cf
            );
        }
    }
    Ok(())
}
