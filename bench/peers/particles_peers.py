"""Peer measurements for `cargo xtask bench particles` (see particles_run.sh).

Cases, matching pbdl-particles' bench entries (pbdl-particles/src/tasks.rs):
  * neighbor_search_2d / neighbor_search_3d: the very point sets of pbdl's bench (100k points
    from the same 64-bit LCG, seed 42, uniform in the unit square / cube, stored as f32) and the
    same radius for ~40 neighbours per point: 2D r = sqrt(40 / (pi N)), 3D r = cbrt(30 / (pi N)).
    Timed: index build + query (median of 7 runs after a warm-up), like pbdl's cell list.
      - scipy cKDTree + query_pairs: unordered pairs i < j as an ndarray (half of pbdl's lists);
        scipy runs this single-threaded.
      - scipy cKDTree + query_ball_point(workers = threads): a Python list per point (with self).
      - open3d.core.nns fixed_radius_index + fixed_radius_search on the CPU: CSR lists (indices,
        distances, splits; with self).
    The size string is pbdl's `n<N>_k<mean neighbours per point, self excluded>`, k counted from
    each peer's own output, so a differing count would show in the table.
  * dam_break_2d_step: PySPH 1.0b2's dam_break_2d example (WCSPH scheme, PEC integrator,
    Wendland quintic, 1 x 2 column in a 4 x 4 tank with 4 wall layers: the geometry of pbdl's
    DamBreak) at --dx 0.05, run to T = t sqrt(2 g / a) = 0.5 like pbdl's bench; then single steps
    are timed, seconds = median wall time per step (pbdl's rows are medians of single steps too).
    The example as shipped gives its particles the h and m of its default dx = 0.03 whatever --dx
    says, so at dx = 0.05 it runs with h/dx = 0.78 (a handful of neighbours); the main row sets
    h = 1.3 dx and m = rho0 dx^2 on the particles, the shipped one is kept as a second row.
    OpenMP with the bench's threads, plus a serial row.

Each case that fails (package missing, API change, build failure) is skipped with a message;
the rows that did run are written. Output: {"rows": [{case, method, size, seconds, unit, error,
error_kind, peer: true, threads}]}; `cargo xtask bench particles` merges it.
"""

import argparse
import contextlib
import json
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
import traceback

import numpy as np

from provenance import stamp, versions_named  # bench/peers/provenance.py, beside this script

THREADS = int(os.environ.get("PBDL_THREADS", "2"))
A_LCG = 6364136223846793005
C_LCG = 1442695040888963407
MASK = (1 << 64) - 1


def row(case, method, size, seconds, unit):
    return {"case": case, "method": method, "size": size, "seconds": float(seconds), "unit": unit,
            "error": None, "error_kind": "", "peer": True, "threads": THREADS}


def uniform_points(n, dim, seed=42):
    """pbdl's `uniform_points` (tasks.rs): s <- s a + c (mod 2^64), value = (s >> 40) / 2^24."""
    s = (seed * A_LCG + C_LCG) & MASK
    out = np.empty(n * dim, dtype=np.float32)
    for i in range(n * dim):
        s = (s * A_LCG + C_LCG) & MASK
        out[i] = (s >> 40) / float(1 << 24)  # exact in f32: a 24-bit integer over 2^24
    return out.reshape(n, dim)


def radius(n, dim):
    """pbdl's radius: computed in f64, then stored as f32."""
    r = math.sqrt(40.0 / (math.pi * n)) if dim == 2 else (30.0 / (math.pi * n)) ** (1.0 / 3.0)
    return float(np.float32(r))


def median_time(fn, warmup=1, reps=7):
    """Median wall time of fn() over reps calls after warmup calls; also the last result."""
    out = None
    for _ in range(warmup):
        out = fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), out


def size_str(n, entries):
    return f"n{n}_k{entries / n:.0f}"


# ---------------------------------------------------------------- neighbour search
def scipy_query_pairs(pts, r):
    from scipy.spatial import cKDTree

    p64 = pts.astype(np.float64)
    secs, pairs = median_time(lambda: cKDTree(p64).query_pairs(r, output_type="ndarray"))
    return secs, 2 * len(pairs)  # directed entries, as pbdl counts them


def scipy_query_ball_point(pts, r):
    from scipy.spatial import cKDTree

    p64 = pts.astype(np.float64)

    def run():
        tree = cKDTree(p64)
        return tree.query_ball_point(p64, r, workers=THREADS, return_sorted=False)

    secs, lists = median_time(run, reps=3)
    return secs, sum(len(l) for l in lists) - len(pts)  # minus self


def open3d_fixed_radius(pts, r):
    import open3d.core as o3c

    pts = np.ascontiguousarray(pts)  # 2D points are accepted as they are

    def run():
        t = o3c.Tensor(pts, dtype=o3c.float32, device=o3c.Device("CPU:0"))
        nns = o3c.nns.NearestNeighborSearch(t)
        if not nns.fixed_radius_index(r):
            raise RuntimeError("fixed_radius_index returned False")
        return nns.fixed_radius_search(t, r)

    secs, (indices, _dist, _splits) = median_time(run)
    return secs, int(indices.shape[0]) - len(pts)  # minus self


def neighbor_cases(n):
    cases = []
    for dim in (2, 3):
        case = f"neighbor_search_{dim}d"
        cases.append((case, dim, "scipy_{v}_ckdtree_query_pairs", "unordered pairs (i < j), ndarray",
                      scipy_query_pairs, "scipy"))
        cases.append((case, dim, "scipy_{v}_ckdtree_query_ball_point", "Python list per point (with self)",
                      scipy_query_ball_point, "scipy"))
        cases.append((case, dim, "open3d_{v}_fixed_radius_search",
                      "CSR lists (with self)", open3d_fixed_radius, "open3d"))
    return cases


def version(module):
    try:
        return __import__(module).__version__
    except Exception:  # the case itself reports the failure
        return "?"


def run_neighbors(n, rows):
    points = {dim: uniform_points(n, dim) for dim in (2, 3)}
    for case, dim, method, unit, fn, module in neighbor_cases(n):
        method = method.format(v=version(module))
        r = radius(n, dim)
        try:
            secs, entries = fn(points[dim], r)
        except ImportError as e:
            hint = ""
            if module == "open3d" and "libusb" in str(e):
                hint = " (install it: sudo apt-get install libusb-1.0-0)"
            print(f"peers: {case} {method} skipped: {e}{hint}", file=sys.stderr)
            continue
        except Exception as e:  # a peer failing is a result to report, not a reason to stop
            print(f"peers: {case} {method} skipped: {type(e).__name__}: {e}", file=sys.stderr)
            if os.environ.get("PBDL_PEERS_DEBUG"):
                traceback.print_exc()
            continue
        print(f"peers: {case} {method}: {secs:.4f} s, N = {n}, r = {r:.6f}, "
              f"{entries / n:.2f} neighbours per point (self excluded)", file=sys.stderr)
        out = row(case, method, size_str(n, entries), secs, unit)
        if "query_pairs" in method:
            out["threads"] = 1  # scipy builds and queries single-threaded here
        rows.extend(stamp([out], __file__, versions_named(module, "numpy")))


# ---------------------------------------------------------------- PySPH dam break
def pysph_dam_break(dx, timed_steps, consistent, openmp):
    """Per-step wall times after T = 0.5, particle counts, steps run, PySPH's version, mean h / dx.

    consistent: the 1.0b2 example gives its particles the h and m of its default dx = 0.03
    whatever --dx says (only the scheme gets h = hdx dx); True sets h = hdx dx and m = rho0 dx^2
    on the particles as well, i.e. the example at dx = 0.05 with ~hdx^2 pi neighbours as intended.
    """
    import pysph
    from pysph.examples import dam_break_2d as example

    t_warm = 0.5 / math.sqrt(2 * 9.81 / example.fluid_column_width)  # T = 0.5, as pbdl's bench
    stamps = []

    class Case(example.DamBreak2D):
        def create_particles(self):
            arrays = super().create_particles()
            if consistent:
                for pa in arrays:
                    pa.h[:] = self.h
                    pa.m[:] = example.ro * self.dx ** 2
            return arrays

    def on_step(solver):
        stamps.append((solver.t, time.perf_counter()))
        if solver.t >= t_warm and sum(1 for t, _ in stamps if t >= t_warm) > timed_steps:
            solver.max_steps = solver.count + 1  # the solve loop ends after this step

    out_dir = tempfile.mkdtemp(prefix="pbdl_pysph_")
    try:
        app = Case(fname="dam_break_2d", output_dir=out_dir)
        argv = ["--dx", f"{dx:g}", "--tf", "10", "--disable-output", "-q"]
        if openmp:
            argv.append("--openmp")
        with contextlib.redirect_stdout(sys.stderr):  # the example prints "Using h = ..."
            app.setup(argv)  # generates and compiles the kernels (not timed)
        app.solver.add_post_step_callback(on_step)
        app.solver.solve(show_progress=False)
        counts = {pa.name: pa.get_number_of_particles() for pa in app.particles}
        fluid = next(pa for pa in app.particles if pa.name == "fluid")
        h_over_dx = float(np.mean(fluid.h)) / dx
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)
    times = [b - a for (t0, a), (_t1, b) in zip(stamps, stamps[1:]) if t0 >= t_warm]
    if len(times) < timed_steps:
        raise RuntimeError(f"only {len(times)} steps after T = 0.5 (wanted {timed_steps})")
    return times[:timed_steps], counts, len(stamps), pysph.__version__, h_over_dx


def run_pysph(dx, timed_steps, rows):
    # The example as intended (h, m for dx) with the bench's threads; the example as shipped; and,
    # since OpenMP barriers suffer most when other processes share the cores, serial code too.
    variants = [(True, THREADS > 1), (False, THREADS > 1)] + ([(True, False)] if THREADS > 1 else [])
    for consistent, openmp in variants:
        variant = "h, m set for dx" if consistent else "example as shipped"
        omp = f"openmp {THREADS} threads" if openmp else "serial"
        name = f"pysph_wcsph_pec ({omp}, {variant})"
        try:
            times, counts, steps, ver, h_over_dx = pysph_dam_break(dx, timed_steps, consistent, openmp)
        except ImportError as e:
            print(f"peers: dam_break_2d_step {name} skipped: {e} (pip install pysph==1.0b2 builds from source "
                  "and needs a C compiler; see particles_run.sh)", file=sys.stderr)
            return
        except Exception as e:  # a peer failing is a result to report, not a reason to stop
            print(f"peers: dam_break_2d_step {name} skipped: {type(e).__name__}: {e}", file=sys.stderr)
            if os.environ.get("PBDL_PEERS_DEBUG"):
                traceback.print_exc()
            continue
        method = name.replace("pysph_", f"pysph_{ver}_", 1)
        n = sum(counts.values())
        secs = statistics.median(times)
        print(f"peers: dam_break_2d_step {method}: median {secs * 1e3:.3f} ms/step, mean {statistics.mean(times) * 1e3:.3f}, "
              f"min {min(times) * 1e3:.3f}, max {max(times) * 1e3:.3f} over {len(times)} steps after T = 0.5; "
              f"{n} particles {counts}, {steps} steps run, fluid h/dx at the end {h_over_dx:.2f}", file=sys.stderr)
        r = row("dam_break_2d_step", method, f"{n}_particles_dx{dx:g}", secs, "step")
        r["threads"] = THREADS if openmp else 1
        rows.extend(stamp([r], __file__, versions_named("pysph", "numpy")))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="20k points and 20 timed steps")
    ap.add_argument("--only", choices=["neighbors", "pysph"], help="run one group of cases")
    args = ap.parse_args()
    rows = []
    if args.only in (None, "neighbors"):
        run_neighbors(20_000 if args.quick else 100_000, rows)
    if args.only in (None, "pysph"):
        run_pysph(0.05, 20 if args.quick else 200, rows)
    with open(args.out + ".tmp", "w") as f:
        json.dump({"rows": rows}, f, indent=2)  # rows are stamped where they are measured
    os.replace(args.out + ".tmp", args.out)
    print(f"peers: wrote {len(rows)} rows to {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
