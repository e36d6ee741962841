"""Reference values for pbdl's cubic B-spline resize (pbdl_core::sample::spline_zoom).

VolSiM resizes its inputs with scipy.ndimage.zoom(data, zoom, order=3) and the defaults
prefilter=True, mode="constant", grid_mode=False. This script writes inputs and scipy's outputs
as float64 .npy files next to it; pbdl-metrics/tests/volsim_resize_tests.rs compares against them.

Run from this directory: python3 make_spline_reference.py   (numpy, scipy; made with scipy 1.17.1)
"""
import numpy as np
import scipy
import scipy.ndimage as ndimage

rng = np.random.default_rng(20231121)


def field(shape):
    # a smooth part plus noise, so that both the interpolation and the prefilter matter
    grids = np.meshgrid(*[np.linspace(0.0, 1.0, n) for n in shape], indexing="ij")
    smooth = np.sin(3.0 * sum(g * (k + 1) for k, g in enumerate(grids)))
    return smooth + 0.3 * rng.standard_normal(shape)


def case(name, shape_in, shape_out):
    x = field(shape_in)
    zoom = [o / i for i, o in zip(shape_in, shape_out)]
    y = ndimage.zoom(x, zoom, order=3, mode="constant", prefilter=True, grid_mode=False)
    assert y.shape == tuple(shape_out), (y.shape, shape_out)
    np.save(f"spline_{name}_in.npy", x)
    np.save(f"spline_{name}_out.npy", y)
    print(name, shape_in, "->", shape_out, "max |y|", np.abs(y).max())


print("scipy", scipy.__version__)
case("9_to_12", (9, 9, 9), (12, 12, 12))
case("12_to_7", (12, 12, 12), (7, 7, 7))
# leading axis unchanged, mixed up/down sampling, a 2-sample axis
case("aniso", (2, 5, 9, 2), (2, 7, 4, 13))
