"""Peer measurements for `cargo xtask bench grid` (see run.sh).

Cases, matching pbdl-grid's bench entries:
  * taylor_green: periodic [0, 2 pi]^2, nu = 0.01, t = 1, dt from CFL 0.5 on |u|max = 1, f32;
    error = relative L2 of the velocity against u = sin x cos y e^{-2 nu t},
    v = -cos x sin y e^{-2 nu t} (each staggered component at its own points).
  * decaying_turbulence (JAX-CFD spectral only): the smooth vorticity of pbdl's `spectral` bench
    to t = 1 at nu = 1e-3 (CFL 0.5 on |u| = 3), f32; error = relative L2 vorticity against JAX-CFD
    itself at 3x the resolution and a 3x shorter step in f64.
  * lid_driven_cavity_re100: unit box, lid speed 1, nu = 0.01, run to t = 20 (steady);
    error = max over Ghia, Ghia & Shin (1982) centreline points of |u - Ghia|, |v - Ghia|.
    JAX-CFD rejects moving walls, so only PhiFlow runs it.

Each case that fails (missing package, solver divergence, API change) is skipped with a message;
the rows that did run are written. Time = seconds per step (median of 3 timed runs of many steps
after a warm-up/jit run). Output: {"rows": [{case, method, size, seconds, unit, error,
error_kind, peer: true, threads}]}.
"""

import argparse
import json
import math
import os
import statistics
import sys
import time
import traceback

import numpy as np

from provenance import stamp, versions_named  # bench/peers/provenance.py, beside this script

NU = 0.01
THREADS = int(os.environ.get("PBDL_THREADS", "2"))
GHIA_U = [  # (y, u) on x = 0.5, Re = 100; Ghia, Ghia & Shin (1982), J. Comput. Phys. 48:387, Table I
    (0.0, 0.0), (0.0547, -0.03717), (0.0625, -0.04192), (0.0703, -0.04775), (0.1016, -0.06434),
    (0.1719, -0.10150), (0.2813, -0.15662), (0.4531, -0.21090), (0.5, -0.20581), (0.6172, -0.13641),
    (0.7344, 0.00332), (0.8516, 0.23151), (0.9531, 0.68717), (0.9609, 0.73722), (0.9688, 0.78871),
    (0.9766, 0.84123), (1.0, 1.0)]
GHIA_V = [  # (x, v) on y = 0.5, Re = 100; Table II
    (0.0, 0.0), (0.0625, 0.09233), (0.0703, 0.10091), (0.0781, 0.10890), (0.0938, 0.12317),
    (0.1563, 0.16077), (0.2266, 0.17507), (0.2344, 0.17527), (0.5, 0.05454), (0.8047, -0.24533),
    (0.8594, -0.22445), (0.9063, -0.16914), (0.9453, -0.10313), (0.9531, -0.08864), (0.9609, -0.07391),
    (0.9688, -0.05906), (1.0, 0.0)]


def row(case, method, n, seconds, error, error_kind):
    return {"case": case, "method": method, "size": f"{n}x{n}", "seconds": float(seconds), "unit": "step",
            "error": None if error is None or not math.isfinite(error) else float(error),
            "error_kind": error_kind, "peer": True, "threads": THREADS}


def tgv_steps(n):
    dx = 2 * math.pi / n
    steps = math.ceil(1.0 / (0.5 * dx))
    return steps, 1.0 / steps


def timed(fn, reps=3):
    """Median wall time of fn() over reps calls (fn must block until done)."""
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def rel_l2(pairs):
    num = sum(float(np.sum((a - b) ** 2)) for a, b in pairs)
    den = sum(float(np.sum(b ** 2)) for _, b in pairs)
    return math.sqrt(num / den)


# ---------------------------------------------------------------- JAX-CFD
def jax_f32():
    """JAX-CFD's rows run in f32, as pbdl's: PhiFlow's JAX backend switches `jax_enable_x64` on
    for the whole process when it first runs, which made every later JAX-CFD row f64 (found on
    2026-11-27: the 64^2+ spectral errors of 1e-10 were f64 numbers)."""
    import jax
    jax.config.update("jax_enable_x64", False)


def jax_cfd_fv_tgv(n):
    jax_f32()
    import jax
    import jax.numpy as jnp
    import jax_cfd.base as cfd

    steps, dt = tgv_steps(n)
    grid = cfd.grids.Grid((n, n), domain=((0, 2 * jnp.pi), (0, 2 * jnp.pi)))
    v0 = cfd.initial_conditions.initial_velocity_field(
        (lambda x, y: jnp.sin(x) * jnp.cos(y), lambda x, y: -jnp.cos(x) * jnp.sin(y)), grid)
    # Second-order central (linear-interpolation) convection, RK4 with a projection per stage.
    step = cfd.equations.semi_implicit_navier_stokes(
        density=1.0, viscosity=NU, dt=dt, grid=grid, convect=cfd.advection.convect_linear,
        time_stepper=cfd.time_stepping.classic_rk4)
    run = jax.jit(cfd.funcutils.repeated(step, steps))
    out = run(v0)
    jax.block_until_ready(out)
    seconds = timed(lambda: jax.block_until_ready(run(v0))) / steps
    d = math.exp(-2 * NU * 1.0)
    pairs = []
    for comp, f in zip(out, (lambda x, y: np.sin(x) * np.cos(y) * d, lambda x, y: -np.cos(x) * np.sin(y) * d)):
        x, y = grid.mesh(comp.offset)
        pairs.append((np.asarray(comp.data, dtype=np.float64), f(np.asarray(x, np.float64), np.asarray(y, np.float64))))
    return seconds, rel_l2(pairs)


def jax_cfd_spectral_tgv(n):
    jax_f32()
    import jax
    import jax.numpy as jnp
    import jax_cfd.base as cfd
    import jax_cfd.spectral as spectral

    steps, dt = tgv_steps(n)
    grid = cfd.grids.Grid((n, n), domain=((0, 2 * jnp.pi), (0, 2 * jnp.pi)))
    x, y = grid.mesh()
    w0 = 2.0 * jnp.sin(x) * jnp.sin(y)  # vorticity dv/dx - du/dy of the vortex
    eq = spectral.equations.NavierStokes2D(NU, grid, drag=0.0, smooth=True)
    step = spectral.time_stepping.crank_nicolson_rk4(eq, dt)
    run = jax.jit(cfd.funcutils.repeated(step, steps))
    w_hat0 = jnp.fft.rfftn(w0)
    w_hat = run(w_hat0)
    jax.block_until_ready(w_hat)
    seconds = timed(lambda: jax.block_until_ready(run(w_hat0))) / steps
    u_hat, v_hat = spectral.utils.vorticity_to_velocity(grid)(w_hat)
    u, v = jnp.fft.irfftn(u_hat, s=(n, n)), jnp.fft.irfftn(v_hat, s=(n, n))
    d = math.exp(-2 * NU * 1.0)
    xn, yn = np.asarray(x, np.float64), np.asarray(y, np.float64)
    pairs = [(np.asarray(u, np.float64), np.sin(xn) * np.cos(yn) * d),
             (np.asarray(v, np.float64), -np.cos(xn) * np.sin(yn) * d)]
    return seconds, rel_l2(pairs)


def decaying_vorticity(x, y, xp):
    """The initial vorticity of pbdl's `spectral` bench (xtask/src/entries/spectral.rs)."""
    return xp.exp(1.5 * xp.cos(x) + xp.sin(y + 0.3)) - xp.exp(1.2 * xp.sin(x - 2.0 * y)) + xp.cos(3.0 * x + y)


def jax_cfd_spectral_decaying(n, nu=1e-3, t_end=1.0, speed=3.0):
    """Decaying turbulence from `decaying_vorticity` to t = 1 (CFL 0.5 on |u| = 3), relative L2
    vorticity error against JAX-CFD itself at 3x the resolution and a 3x shorter step, in f64
    (cell centres coincide at the odd ratio)."""
    import jax
    import jax.numpy as jnp
    import jax_cfd.base as cfd
    import jax_cfd.spectral as spectral

    def run(m, dt, steps, dtype):
        grid = cfd.grids.Grid((m, m), domain=((0, 2 * jnp.pi), (0, 2 * jnp.pi)))
        x, y = grid.mesh()
        w0 = decaying_vorticity(x, y, jnp)
        w0 = (w0 - jnp.mean(w0)).astype(dtype)
        eq = spectral.equations.NavierStokes2D(nu, grid, drag=0.0, smooth=True)
        fn = jax.jit(cfd.funcutils.repeated(spectral.time_stepping.crank_nicolson_rk4(eq, dt), steps))
        w_hat0 = jnp.fft.rfftn(w0)
        out = fn(w_hat0)
        jax.block_until_ready(out)
        return fn, w_hat0, np.asarray(jnp.fft.irfftn(out, s=(m, m)), np.float64)

    jax_f32()
    steps = math.ceil(t_end / (0.5 * (2 * math.pi / n) / speed))
    dt = t_end / steps
    fn, w_hat0, w = run(n, dt, steps, jnp.float32)
    seconds = timed(lambda: jax.block_until_ready(fn(w_hat0))) / steps
    jax.config.update("jax_enable_x64", True)
    try:
        _, _, ref = run(3 * n, dt / 3, 3 * steps, jnp.float64)
    finally:
        jax.config.update("jax_enable_x64", False)
    # JAX-CFD's grid.mesh() is [x, y] indexed; the cell (i, j) of the coarse grid is (3i+1, 3j+1).
    fine = ref[1::3, 1::3]
    return seconds, float(np.sqrt(np.sum((w - fine) ** 2) / np.sum(fine ** 2)))


# ---------------------------------------------------------------- PhiFlow
def phiflow_modules(backend):
    if backend == "jax":
        import phi.jax.flow as flow
    else:
        import phi.flow as flow
    flow.math.set_global_precision(32)
    return flow


def phi_components(v):
    """The staggered components of a PhiFlow StaggeredGrid as numpy arrays [y, x]."""
    return [np.asarray(v.vector[d].values.numpy("y,x"), dtype=np.float64) for d in ("x", "y")]


def phiflow_step(flow, nu, dt):
    @flow.jit_compile
    def step(v, p):
        v = flow.advect.semi_lagrangian(v, v, dt)
        v = flow.diffuse.explicit(v, nu, dt)
        v, p = flow.fluid.make_incompressible(v, (), flow.Solve("auto", 1e-5, 1e-5, x0=p))
        return v, p
    return step


def run_steps(step, v, p, steps):
    for _ in range(steps):
        v, p = step(v, p)
    # Force evaluation (JAX is asynchronous).
    _ = v.vector["x"].values.numpy("y,x")
    return v, p


def phiflow_tgv(n, backend):
    flow = phiflow_modules(backend)
    steps, dt = tgv_steps(n)
    box = flow.Box(x=2 * math.pi, y=2 * math.pi)
    base = flow.StaggeredGrid(0, flow.extrapolation.PERIODIC, x=n, y=n, bounds=box)

    def tgv(d):
        # Sampled at each component's own face centres. (PhiFlow 3.4 calls a function initialiser
        # with every face position of every component and cannot squeeze a vector result, so the
        # values are built here and attached with with_values.)
        px = base.vector["x"].points.numpy("x,y,vector").astype(np.float64)
        py = base.vector["y"].points.numpy("x,y,vector").astype(np.float64)
        u = np.sin(px[..., 0]) * np.cos(px[..., 1]) * d
        w = -np.cos(py[..., 0]) * np.sin(py[..., 1]) * d
        comps = {"x": flow.math.tensor(u, flow.spatial("x,y")), "y": flow.math.tensor(w, flow.spatial("x,y"))}
        return base.with_values(flow.math.stack(comps, flow.math.dual("vector")))

    v0 = tgv(1.0)
    step = phiflow_step(flow, NU, dt)
    _, p0 = step(v0, None)  # trace / warm up
    v, _ = run_steps(step, v0, p0, steps)
    reps_steps = min(steps, 50)
    seconds = timed(lambda: run_steps(step, v0, p0, reps_steps)) / reps_steps
    exact = tgv(math.exp(-2 * NU))
    return seconds, rel_l2(list(zip(phi_components(v), phi_components(exact))))


def interp(xs, ys, x):
    return float(np.interp(x, xs, ys))


def phiflow_cavity(n, backend, t_end=20.0):
    flow = phiflow_modules(backend)
    h = 1.0 / n
    dt = min(0.5 * h, 0.2 * h * h / NU)  # CFL 0.5 on the lid speed, explicit-diffusion limit
    steps = math.ceil(t_end / dt)
    dt = t_end / steps
    boundary = {"x": 0, "y-": 0, "y+": flow.vec(x=1, y=0)}
    v0 = flow.StaggeredGrid(0, boundary, x=n, y=n, bounds=flow.Box(x=1, y=1))
    step = phiflow_step(flow, NU, dt)
    v, p = step(v0, None)
    t = time.perf_counter()
    v, p = run_steps(step, v, p, steps - 1)
    seconds = (time.perf_counter() - t) / (steps - 1)
    u, w = phi_components(v)  # u: [n, n+1] faces x = i h; w: [n+1, n] faces y = j h
    yc = (np.arange(n) + 0.5) * h
    uline = np.concatenate([[0.0], u[:, n // 2], [1.0]])
    vline = np.concatenate([[0.0], w[n // 2, :], [0.0]])
    coords = np.concatenate([[0.0], yc, [1.0]])
    err_u = max(abs(interp(coords, uline, y) - g) for y, g in GHIA_U)
    err_v = max(abs(interp(coords, vline, x) - g) for x, g in GHIA_V)
    return seconds, max(err_u, err_v)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", help="run only methods whose name contains this; merge into --out")
    args = ap.parse_args()
    sizes = [32, 64] if args.quick else [32, 64, 128, 256]
    cases = []
    for n in sizes:
        cases.append(("taylor_green", "jax_cfd_fv_rk4", n, "rel_l2_vs_analytic", lambda n=n: jax_cfd_fv_tgv(n)))
        cases.append(("taylor_green", "jax_cfd_spectral_cn_rk4", n, "rel_l2_vs_analytic",
                      lambda n=n: jax_cfd_spectral_tgv(n)))
        cases.append(("taylor_green", "phiflow_jax_semi_lagrangian", n, "rel_l2_vs_analytic",
                      lambda n=n: phiflow_tgv(n, "jax")))
    for n in [64, 128] if not args.quick else [32]:
        cases.append(("decaying_turbulence", "jax_cfd_spectral_cn_rk4", n, "rel_l2_vorticity_vs_3x_finer",
                      lambda n=n: jax_cfd_spectral_decaying(n)))
    for n in [32, 64] if not args.quick else [32]:
        cases.append(("taylor_green", "phiflow_numpy_semi_lagrangian", n, "rel_l2_vs_analytic",
                      lambda n=n: phiflow_tgv(n, "numpy")))
    for n in [32, 64] if not args.quick else [32]:
        cases.append(("lid_driven_cavity_re100", "phiflow_jax_semi_lagrangian", n, "max_centreline_abs_vs_ghia",
                      lambda n=n: phiflow_cavity(n, "jax")))
    print("peers: lid_driven_cavity with JAX-CFD skipped: JAX-CFD rejects moving-wall boundaries", file=sys.stderr)
    rows = []
    if args.only:
        cases = [c for c in cases if args.only in c[1]]
        if os.path.exists(args.out):  # keep the other methods' rows of an earlier full run
            with open(args.out) as f:
                names = {c[1] for c in cases}
                rows = [r for r in json.load(f)["rows"] if r["method"] not in names]
    for case, method, n, kind, fn in cases:
        try:
            seconds, err = fn()
            print(f"peers: {case} {method} {n}^2: {seconds * 1e3:.3f} ms/step, error {err:.3e}", file=sys.stderr)
            modules = ("jax", "jax_cfd", "numpy") if method.startswith("jax_cfd") else ("phi", "jax", "numpy")
            rows.extend(stamp([row(case, method, n, seconds, err, kind)], __file__, versions_named(*modules)))
        except Exception as e:  # a peer failing is a result to report, not a reason to stop
            print(f"peers: {case} {method} {n}^2 skipped: {type(e).__name__}: {e}", file=sys.stderr)
            if os.environ.get("PBDL_PEERS_DEBUG"):
                traceback.print_exc()
    with open(args.out + ".tmp", "w") as f:
        json.dump({"rows": rows}, f, indent=2)
    os.replace(args.out + ".tmp", args.out)
    print(f"peers: wrote {len(rows)} rows to {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
