"""The benchmarks and the visibility study: the affine/non-affine split obeys its laws, the build benchmark runs."""
from __future__ import annotations

import numpy as np

from appdgen.calib.defaults import default_calibration
from appdgen.geometry.maps import rectify
from appdgen.synth import scale_calibration
from helpers import load_script
from studies import visibility

KITTI_02_QUARTER = scale_calibration(default_calibration("02"), 0.25)  # the demo's camera, 348x128



def test_affine_displacement_leaves_nothing_and_a_bend_is_measured():
    v, u = np.mgrid[0:128:4, 0:348:4].astype(float)
    u, v = u.ravel(), v.ravel()
    assert visibility.non_affine_px(u, v, 1.5 + 0.01 * u - 0.02 * v, -0.7 + 0.03 * u) < 1e-9
    bend = 1e-3 * (u - 174) ** 2  # a parabola: sagitta 30 px, mean |residual| a known fraction of it
    expected = np.abs(bend - np.polyval(np.polyfit(u, bend, 1), u)).mean()
    assert abs(visibility.non_affine_px(u, v, bend, 0 * u) - expected) < 1e-9


def test_split_of_the_reference_is_zero_and_of_a_shift_mostly_affine():
    ref = rectify(KITTI_02_QUARTER)
    appd, rest = visibility.split(ref, KITTI_02_QUARTER)
    assert appd == 0.0 and rest < 1e-4  # float32 maps round-trip to ~1e-5 px
    appd, rest = visibility.split(ref, KITTI_02_QUARTER.perturb(cx=0.05))
    assert appd > 5 and 0 < rest < 0.3 * appd  # a principal-point change reads mostly as a shift


def test_bench_build_filters_write_pngs_that_decode_to_the_pixels():
    import zlib

    import cv2

    from appdgen.dataset.encoders import png_file

    bench = load_script("bench_build")
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (9, 13, 3), dtype=np.uint8)
    for kind in ("None", "Sub", "Up", "Average"):
        rows = bench.filtered_rows(image, kind)
        code = {"None": 0, "Sub": 1, "Up": 2, "Average": 3}[kind]
        assert rows.shape == (9, 13 * 3 + 1) and (rows[:, 0] == code).all()
        data = png_file(13, 9, 3, zlib.compress(rows.tobytes()))
        assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), image), kind
