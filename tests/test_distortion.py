"""The numpy lens model against OpenCV, on the real KITTI camera, and its inverse."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import KITTI_2011_09_26
from hypothesis import given, settings
from hypothesis import strategies as st

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.distortion import (
    distort_normalized,
    distort_to_pixels,
    project,
    radial_fold_radius,
    undistort_pixels,
)

# KITTI raw 2011_09_26, camera 02 (published calib_cam_to_cam.txt).


def _raw_grid(calib: Calibration, step: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel positions covering the whole image, corners and edges included."""
    us = np.unique(np.r_[np.arange(0, calib.width, step), calib.width - 1]).astype(float)
    vs = np.unique(np.r_[np.arange(0, calib.height, step), calib.height - 1]).astype(float)
    return np.meshgrid(us, vs)


def _cv2_undistort(points: np.ndarray, calib: Calibration) -> np.ndarray:
    """OpenCV's iterative undistortion to normalized coordinates, run to convergence."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    src = points.reshape(-1, 1, 2).astype(np.float64)
    iterative = getattr(cv2, "undistortPointsIter", None)  # OpenCV 4; OpenCV 5 takes criteria in undistortPoints
    if iterative is not None:
        return iterative(src, calib.K, calib.D, None, None, criteria).reshape(-1, 2)
    return cv2.undistortPoints(src, calib.K, calib.D, criteria=criteria).reshape(-1, 2)


def test_project_matches_cv2_project_points():
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.9, 0.9, 500), rng.uniform(-0.35, 0.35, 500)
    z = rng.uniform(0.5, 80.0, 500)
    points = np.stack([x * z, y * z, z], 1)
    camera = KITTI_2011_09_26["02"]
    expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.D)
    u, v = project(points, KITTI_2011_09_26["02"])
    np.testing.assert_allclose(np.stack([u, v], 1), expected.reshape(-1, 2), atol=1e-8)
    xd, yd = distort_normalized(x, y, KITTI_2011_09_26["02"])
    np.testing.assert_allclose(KITTI_2011_09_26["02"].fx * xd + KITTI_2011_09_26["02"].cx, expected[:, 0, 0], atol=1e-8)
    np.testing.assert_allclose(distort_to_pixels(x, y, KITTI_2011_09_26["02"])[1], expected[:, 0, 1], atol=1e-8)


def test_undistort_matches_cv2_over_the_whole_image():
    u, v = _raw_grid(KITTI_2011_09_26["02"])
    x, y = undistort_pixels(u, v, KITTI_2011_09_26["02"])
    assert x.shape == u.shape and x.dtype == np.float64
    expected = _cv2_undistort(np.stack([u.ravel(), v.ravel()], 1), KITTI_2011_09_26["02"])
    np.testing.assert_allclose(np.stack([x.ravel(), y.ravel()], 1), expected, atol=1e-9)


def test_round_trips_are_identity():
    u, v = _raw_grid(KITTI_2011_09_26["02"], step=3)
    x, y = undistort_pixels(u, v, KITTI_2011_09_26["02"])
    xd, yd = distort_normalized(x, y, KITTI_2011_09_26["02"])
    np.testing.assert_allclose(xd, (u - KITTI_2011_09_26["02"].cx) / KITTI_2011_09_26["02"].fx, atol=1e-9, rtol=0)
    np.testing.assert_allclose(yd, (v - KITTI_2011_09_26["02"].cy) / KITTI_2011_09_26["02"].fy, atol=1e-9, rtol=0)
    # And the other way: undistort ∘ distort on undistorted points inside the fold radius.
    gx, gy = np.meshgrid(np.linspace(-1.0, 1.0, 41), np.linspace(-0.4, 0.4, 17))
    back = undistort_pixels(*distort_to_pixels(gx, gy, KITTI_2011_09_26["02"]), KITTI_2011_09_26["02"])
    np.testing.assert_allclose(back[0], gx, atol=1e-9, rtol=0)
    np.testing.assert_allclose(back[1], gy, atol=1e-9, rtol=0)


def test_no_distortion_is_the_pinhole():
    pinhole = KITTI_2011_09_26["02"].replace(k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0)
    u, v = _raw_grid(pinhole, step=50)
    x, y = undistort_pixels(u, v, pinhole)
    np.testing.assert_array_equal(x, (u - pinhole.cx) / pinhole.fx)
    np.testing.assert_array_equal(y, (v - pinhole.cy) / pinhole.fy)
    assert radial_fold_radius(pinhole) == float("inf")


def test_fold_over_raises_or_marks_nan():
    folding = Calibration(100, 100, 50.0, 50.0, 50.0, 50.0, k1=-0.6)  # r(1 − 0.6 r²) peaks at r ≈ 0.75 < corner
    assert radial_fold_radius(folding) == pytest.approx(np.sqrt(1 / 1.8))
    u, v = np.array([0.0, 50.0, 60.0]), np.array([0.0, 50.0, 55.0])
    with pytest.raises(AppdgenError, match=r"cannot be inverted at 1 point.*\(0\.0, 0\.0\).*folds over"):
        undistort_pixels(u, v, folding)
    x, y = undistort_pixels(u, v, folding, on_failure="nan")
    assert np.isnan(x[0]) and np.isnan(y[0]) and np.all(np.isfinite(x[1:]))
    # Far outside the image Newton may find a mirrored root past the fold: that is a failure too.
    with pytest.raises(AppdgenError, match="folds over"):
        undistort_pixels(np.array([1e5]), np.array([0.0]), KITTI_2011_09_26["02"])


def test_project_rejects_points_behind_the_camera():
    with pytest.raises(AppdgenError, match="not in front"):
        project(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), KITTI_2011_09_26["02"])
    with pytest.raises(AppdgenError, match="shape"):
        project(np.zeros((4, 2)), KITTI_2011_09_26["02"])


@settings(max_examples=40, deadline=None)
@given(
    k1=st.floats(-0.4, 0.4), k2=st.floats(-0.2, 0.2), k3=st.floats(-0.07, 0.07),
    p1=st.floats(-0.005, 0.005), p2=st.floats(-0.005, 0.005),
)
def test_round_trip_for_moderate_lenses(k1, k2, k3, p1, p2):
    calib = KITTI_2011_09_26["02"].replace(k1=k1, k2=k2, k3=k3, p1=p1, p2=p2)
    gx, gy = np.meshgrid(np.linspace(-0.6, 0.6, 13), np.linspace(-0.3, 0.3, 7))
    x, y = undistort_pixels(*distort_to_pixels(gx, gy, calib), calib)
    np.testing.assert_allclose(x, gx, atol=1e-9, rtol=0)
    np.testing.assert_allclose(y, gy, atol=1e-9, rtol=0)
