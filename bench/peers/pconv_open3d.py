"""Open3D's ContinuousConv (open3d.ml.tf, CPU) timed on the cases of pbdl-pconv's bench
(pbdl-pconv/benches/pconv.rs): N uniform random points in the unit box, radius for ~40
neighbours (3D), C_in = C_out = 32, f32, CConv's filter (4^3 linear, volume-preserving
ball-to-cube, poly6 window, no normalisation, no bias). Neighbours are the periodic pairs within
the radius (SciPy cKDTree with boxsize 1, self excluded), built once outside the timing and
passed as user_neighbors_*, so, as in pbdl's rows, the timed part is offsets + convolution
(forward) or that plus the gradients of sum(out * R). Open3D's op has gradients for features
and kernel only, not for positions (pbdl's rows include the position gradient).

Open3D's convolution is 3D only (2D would be a 3D filter on a flat point set): 3D rows only.
Prints one JSON object per case on stdout.
"""
import json
import os
import sys
import time

import numpy as np
import tensorflow as tf

threads = int(os.environ.get("PBDL_THREADS", "2"))
tf.config.threading.set_intra_op_parallelism_threads(threads)
tf.config.threading.set_inter_op_parallelism_threads(1)

import open3d.ml.tf as ml3d  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

C = 32


def radius(dim, n, neighbours):
    if dim == 2:
        return (neighbours / (np.pi * n)) ** 0.5
    return (3.0 * neighbours / (4.0 * np.pi * n)) ** (1.0 / 3.0)


def timed(f, runs):
    f()  # warm-up (graph tracing, allocations)
    t = []
    for _ in range(runs):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return float(np.median(t)), float(min(t)), float(max(t))


def case(n, runs):
    rng = np.random.default_rng(42 + n)
    r = radius(3, n, 40.0)
    x = rng.random((n, 3))
    tree = cKDTree(x, boxsize=1.0)
    lists = tree.query_ball_point(x, r, return_sorted=True)
    idx = [np.asarray([j for j in l if j != i], dtype=np.int32) for i, l in enumerate(lists)]
    splits = np.zeros(n + 1, dtype=np.int64)
    splits[1:] = np.cumsum([len(v) for v in idx])
    nbr = np.concatenate(idx).astype(np.int32)
    pairs = int(splits[-1])

    conv = ml3d.layers.ContinuousConv(
        filters=C,
        kernel_size=[4, 4, 4],
        activation=None,
        use_bias=False,
        align_corners=True,
        coordinate_mapping="ball_to_cube_volume_preserving",
        interpolation="linear",
        normalize=False,
        window_function="poly6",
        in_channels=C,
    )
    pos = tf.Variable(x.astype(np.float32))
    feat = tf.Variable(rng.uniform(-1, 1, (n, C)).astype(np.float32))
    rr = tf.constant(rng.uniform(-1, 1, (n, C)).astype(np.float32))
    extents = tf.constant(2.0 * r, dtype=tf.float32)  # the filter's diameter
    nbr_t, splits_t = tf.constant(nbr), tf.constant(splits)
    imp = tf.ones((pairs,), dtype=tf.float32)

    def fwd():
        return conv(feat, pos, pos, extents, user_neighbors_index=nbr_t, user_neighbors_row_splits=splits_t,
                    user_neighbors_importance=imp)

    def fwd_bwd():
        with tf.GradientTape() as tape:
            out = fwd()
            loss = tf.reduce_sum(out * rr)
        g = tape.gradient(loss, [feat, conv.kernel, pos])
        # Open3D's op has no gradient for positions (None): only features and kernel.
        return [None if v is None else v.numpy() for v in g]

    fwd()  # builds the kernel variable
    with tf.GradientTape() as tape:
        loss = tf.reduce_sum(fwd() * rr)
    has_grad = [v is not None for v in tape.gradient(loss, [feat, conv.kernel, pos])]
    rows = []
    for name, f in [("forward", lambda: fwd().numpy()), ("forward_backward", fwd_bwd)]:
        med, lo, hi = timed(f, runs)
        rows.append({"case": f"pconv_{n // 1000}k_3d/{name}/cconv", "peer": "open3d_ml_tf_ContinuousConv",
                     "n": n, "pairs": pairs, "radius": r, "threads": threads, "runs": runs,
                     "median_s": med, "min_s": lo, "max_s": hi,
                     "gradients": [w for w, h in zip(["features", "kernel", "positions"], has_grad) if h]
                     if name == "forward_backward" else []})
    return rows


def main():
    sizes = [int(s) for s in (sys.argv[1:] or ["10000", "100000"])]
    for n in sizes:
        for row in case(n, 5 if n <= 10000 else 3):
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
