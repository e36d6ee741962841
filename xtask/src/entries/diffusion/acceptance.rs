//! pbdl-diffusion's stress entry `acceptance`: the `#[ignore]`d acceptance tests behind the
//! README's ACDM, SMDP and uncertainty-surrogate claims, run in release as child processes
//! ([`crate::acceptance`]). The full run takes about 4.5 hours on 2 cores (ACDM ~2.7 h with
//! its rollouts, SMDP experts ~19 min per seed, the reduced wake surrogate ~49 min); `--quick`
//! runs only the SMDP affine test (3.5 min), which fails (README: not met at every t).

use super::smdp::Entries;
use crate::acceptance::AcceptanceTest;
use crate::registry::{Entry, StressCheck, TaskContext, TaskResult};

/// This part's entries (stress only).
pub fn entries() -> Entries {
    (
        vec![],
        vec![],
        vec![Entry {
            name: "acceptance",
            about: "The README's ACDM, SMDP and uncertainty-surrogate acceptance: runs their #[ignore]d tests in release (about 4.5 h; quick: the 3.5-min SMDP affine test).",
            run: stress_acceptance,
        }],
    )
}

/// The `#[ignore]`d tests behind the README's ACDM, SMDP and uncertainty-surrogate claims (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "acdm_acceptance",
        test: "acdm_beats_one_step_unet_on_held_out_reynolds_numbers",
        claim: "ACDM on held-out Re 100/950: finite, |ds/dt| 0.5-2x truth, Strouhal within 10%; one-step U-Net misses; spread > 0",
        minutes: 160.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "smdp_exact",
        test: "quadratic_split_experts_seed0",
        claim: "SMDP quadratic toy, odd split experts, seed 0: ODE and SDE hits >= 95%, ODE sign kept >= 99%, posterior within 0.05 of the digest",
        minutes: 19.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "smdp_exact",
        test: "quadratic_split_experts_seed1",
        claim: "SMDP quadratic toy, odd split experts, seed 1: ODE and SDE hits >= 95%, ODE sign kept >= 99%, posterior within 0.05 of the digest",
        minutes: 19.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "smdp_toy",
        test: "affine_learned_score_matches_the_analytic_score",
        claim: "SMDP affine score: rel. error < 0.10 pooled and at every t (README: not met at every t)",
        minutes: 3.5,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "smdp_heat",
        test: "heat_corrected_reconstructions_beat_the_plain_inverse_step",
        claim: "SMDP heat 32^2: ODE below the plain inverse step on MSE and spectral error, SDE on spectral error",
        minutes: 6.0,
        env: &[("RAYON_NUM_THREADS", "1")],
    },
    AcceptanceTest {
        package: "pbdl-diffusion",
        file: "uncertainty_wake",
        test: "wake_surrogate_predicts_mean_and_spread_on_unseen_reynolds_numbers",
        claim: "uncertainty surrogate (reduced: 16^2, small AifNet, 4000 updates): mean error < 5%, std correlation > 0.8, std within 20% at 6 test Re",
        minutes: 49.0,
        env: &[("PBDL_WAKE_POOL", "2"), ("PBDL_WAKE_NET", "small"), ("PBDL_WAKE_STEPS", "4000"), ("PBDL_WAKE_SAMPLES", "50")],
    },
];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}
