"""The learnability diagnostics in benchmarks/: the affine/non-affine split obeys its laws."""
from __future__ import annotations

import numpy as np

from appdgen.calib.defaults import default_calibration
from appdgen.geometry.maps import rectify
from appdgen.synth import scale_calibration
from helpers import load_script

KITTI_02_QUARTER = scale_calibration(default_calibration("02"), 0.25)  # the demo's camera, 348x128


visibility = load_script("visibility")


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
