"""Times the official LSiM and VolSiM code (PyTorch, CPU) on the cases of `cargo xtask bench metrics`.

The official repositories are not part of pbdl: clone them and pass their paths,

    git clone https://github.com/tum-pbs/LSIM   /some/where/LSIM
    git clone https://github.com/tum-pbs/VOLSIM /some/where/VOLSIM
    bench/peers/metrics_run.sh --lsim /some/where/LSIM --volsim /some/where/VOLSIM

Cases (same shapes and value ranges as pbdl's rows; uniform random fields from numpy):
  lsim_224          one 128x128 pair, computeDistance with its defaults (nearest resize to 224)
  lsim_native       the same pair without resizing (interpolateTo=None)
  lsim_224_batch16  16 pairs of 128x128 in one call, time per pair
  lsim_example      the published plume example (../shared/data/lsim-example), with the error
                    against the published distances 0.3791 / 0.4433
  volsim_3scales    one 64^3 pair, MS_3scales.pth, normalize=True, interpolate=False
  volsim_3scales_resize64  one 48^3 pair, interpolate=True (cubic spline to 64^3)
Each time is the median of --reps calls after one warm-up call, torch.set_num_threads(threads).

The official LSiM module imports torchvision, matplotlib and imageio for parts that LSiM's own
base network does not use; when one of them is not installed, an empty stand-in module is put
in its place (printed), so that the official distance code itself runs unchanged.
"""
import argparse
import json
import os
import statistics
import sys
import time
import types

import numpy as np

from provenance import stamp, versions_of  # bench/peers/provenance.py, beside this script

PUBLISHED_LSIM_EXAMPLE = (0.3791, 0.4433)


def median_seconds(fn, reps):
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def stand_in(name):
    """Registers an empty module for an optional import that the distance code never uses."""
    try:
        __import__(name)
    except ImportError:
        print(f"peers: {name} not installed; an empty stand-in module is imported instead", file=sys.stderr)
        mod = types.ModuleType(name)
        if name == "torchvision":
            mod.models = types.ModuleType("torchvision.models")
            mod.transforms = types.ModuleType("torchvision.transforms")
            sys.modules["torchvision.models"] = mod.models
            sys.modules["torchvision.transforms"] = mod.transforms
        if name == "matplotlib":
            for sub in ("pyplot", "cm"):
                m = types.ModuleType(f"matplotlib.{sub}")
                setattr(mod, sub, m)
                sys.modules[f"matplotlib.{sub}"] = m
        sys.modules[name] = mod


def torch_load_full():
    """The official checkpoints hold plain Python objects next to the tensors; torch >= 2.6 loads
    only tensors by default, so restore the old default for these trusted files."""
    import torch

    original = torch.load

    def load(*a, **k):
        k.setdefault("weights_only", False)
        return original(*a, **k)

    torch.load = load


def row(case, method, size, seconds, threads, error=None, error_kind=""):
    return {"case": case, "method": method, "size": size, "seconds": seconds, "unit": "pair", "error": error,
            "error_kind": error_kind, "peer": True, "threads": threads}


def lsim_rows(repo, threads, reps, example_dir):
    import torch
    for name in ("torchvision", "matplotlib", "imageio"):
        stand_in(name)
    sys.path.insert(0, os.path.join(repo, "Source"))
    from LSIM.distance_model import DistanceModel

    model = DistanceModel(baseType="lsim", isTrain=False, useGPU=False)
    model.load(os.path.join(repo, "Models", "LSiM.pth"))
    method = f"lsim_official_pytorch_{torch.__version__}_cpu"
    rng = np.random.default_rng(10)
    a, b = rng.random((128, 128, 1)), rng.random((128, 128, 1))
    rows = [
        row("lsim_224", method, "128x128->224", median_seconds(lambda: model.computeDistance(a, b), reps), threads),
        row("lsim_native", method, "128x128",
            median_seconds(lambda: model.computeDistance(a, b, interpolateTo=None), reps), threads),
    ]
    a16, b16 = rng.random((16, 128, 128, 1)), rng.random((16, 128, 128, 1))
    s = median_seconds(lambda: model.computeDistance(a16, b16), min(reps, 3)) / 16
    rows.append(row("lsim_224_batch16", method, "16x128x128->224", s, threads))
    if example_dir and os.path.isdir(example_dir):
        ref, pa, pb = (np.load(os.path.join(example_dir, f"lsim_example_plume{n}.npy")) for n in ("Reference", "A", "B"))
        da, db = model.computeDistance(ref, pa)[0], model.computeDistance(ref, pb)[0]
        err = max(abs(da - PUBLISHED_LSIM_EXAMPLE[0]), abs(db - PUBLISHED_LSIM_EXAMPLE[1]))
        print(f"peers: official LSiM on the example: {da:.4f} / {db:.4f}", file=sys.stderr)
        s = median_seconds(lambda: model.computeDistance(ref, pa), reps)
        rows.append(row("lsim_example", method, "256x256->224", s, threads, float(err),
                        "abs diff vs published LSiM example"))
    return rows, versions_of(torch, np)


def volsim_rows(repo, threads, reps):
    import torch
    import scipy
    sys.path.insert(0, os.path.join(repo, "src"))
    from volsim.distance_model import DistanceModel

    model = DistanceModel.load(os.path.join(repo, "models", "MS_3scales.pth"), useGPU=False)
    method = f"volsim_official_pytorch_{torch.__version__}_cpu"
    rng = np.random.default_rng(30)
    a, b = rng.random((64, 64, 64, 1)).astype(np.float32), rng.random((64, 64, 64, 1)).astype(np.float32)
    rows = [row("volsim_3scales", method, "64x64x64",
                median_seconds(lambda: model.computeDistance(a, b, normalize=True, interpolate=False), min(reps, 3)),
                threads)]
    a, b = rng.random((48, 48, 48, 1)).astype(np.float32), rng.random((48, 48, 48, 1)).astype(np.float32)
    rows.append(row("volsim_3scales_resize64", method, "48^3->64^3",
                    median_seconds(lambda: model.computeDistance(a, b, normalize=True, interpolate=True), min(reps, 3)),
                    threads))
    return rows, versions_of(torch, np, scipy)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--lsim", help="checkout of https://github.com/tum-pbs/LSIM")
    ap.add_argument("--volsim", help="checkout of https://github.com/tum-pbs/VOLSIM")
    ap.add_argument("--example", default=os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data",
                                                      "lsim-example"))
    ap.add_argument("--reps", type=int, default=7)
    args = ap.parse_args()
    import torch
    threads = int(os.environ.get("PBDL_THREADS", "2"))
    torch.set_num_threads(threads)
    torch_load_full()
    rows = []
    for name, path, fn in [("LSiM", args.lsim, lambda p: lsim_rows(p, threads, args.reps, args.example)),
                           ("VolSiM", args.volsim, lambda p: volsim_rows(p, threads, args.reps))]:
        if not path:
            print(f"peers: {name} skipped: pass the path of its official checkout (--{name.lower()})", file=sys.stderr)
            continue
        with torch.no_grad():
            measured, versions = fn(path)
        for r in measured:
            print(f"peers: {r['case']} {r['method']}: {r['seconds'] * 1e3:.1f} ms per pair", file=sys.stderr)
        rows += stamp(measured, __file__, versions)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out + ".tmp", "w") as f:
        json.dump({"rows": rows}, f, indent=2)
    os.replace(args.out + ".tmp", args.out)
    print(f"peers: wrote {len(rows)} rows to {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
