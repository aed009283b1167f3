"""Procedural raw frames: determinism, sizes, and that Θ's rectification straightens them again."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from appdgen.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.synth import (
    _distortion_maps,
    frame_rng,
    render_frame,
    render_ideal,
    scale_calibration,
    synthesize,
)
from conftest import KITTI_2011_09_26



def test_scale_calibration():
    small = scale_calibration(KITTI_2011_09_26["02"], 0.25)
    assert small.size == (348, 128)
    np.testing.assert_allclose(small.K, KITTI_2011_09_26["02"].K * [[0.25], [0.25], [1.0]])
    np.testing.assert_array_equal(small.D, KITTI_2011_09_26["02"].D)
    assert scale_calibration(KITTI_2011_09_26["02"], 1.0) is KITTI_2011_09_26["02"]
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(AppdgenError, match="scale"):
            scale_calibration(KITTI_2011_09_26["02"], bad)


def test_frame_shape_dtype_and_determinism():
    frame = render_frame(KITTI_2011_09_26["02"], frame_rng(3, 0), scale=0.25)
    assert frame.shape == (128, 348, 3) and frame.dtype == np.uint8
    assert render_frame(KITTI_2011_09_26["02"], frame_rng(3, 0), scale=0.25).tobytes() == frame.tobytes()
    others = [render_frame(KITTI_2011_09_26["02"], frame_rng(s, i), scale=0.25) for s, i in ((3, 1), (4, 0))]
    for other in others:  # another index or seed: another street, not a shifted copy of the same one
        assert np.abs(other.astype(int) - frame).mean() > 10
    assert frame.std() > 20  # rich: not a flat image


def test_synthesize_writes_deterministic_pngs_in_any_order(tmp_path):
    calls = []
    paths = synthesize(KITTI_2011_09_26["02"], 3, tmp_path / "a", seed=9, scale=0.25, progress=calls.append)
    assert [p.name for p in paths] == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    assert calls == [1, 1, 1]
    again = synthesize(KITTI_2011_09_26["02"], 3, tmp_path / "b", seed=9, scale=0.25)
    assert [p.read_bytes() for p in paths] == [p.read_bytes() for p in again]
    # Frame 2 does not depend on frames 0 and 1 having been made first.
    np.testing.assert_array_equal(cv2.imread(str(paths[2])), render_frame(KITTI_2011_09_26["02"], frame_rng(9, 2), scale=0.25))
    assert synthesize(KITTI_2011_09_26["02"], 0, tmp_path / "c", seed=9) == []
    with pytest.raises(AppdgenError, match="frames"):
        synthesize(KITTI_2011_09_26["02"], -1, tmp_path / "d", seed=9)


def test_canvas_holds_every_sample():
    map_x, map_y, K, (w, h) = _distortion_maps(KITTI_2011_09_26["02"])
    assert map_x.min() >= 2 and map_y.min() >= 2 and map_x.max() <= w - 3 and map_y.max() <= h - 3
    assert w > KITTI_2011_09_26["02"].width and h > KITTI_2011_09_26["02"].height  # barrel distortion: the undistorted view is wider


def _blurred(image: np.ndarray) -> np.ndarray:
    """Grey levels with sensor noise and resampling jitter smoothed away."""
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), 1.0)


@pytest.mark.parametrize("index", [0, 1])
def test_rectifying_with_theta_gives_the_ideal_pinhole_image(index):
    calib = scale_calibration(KITTI_2011_09_26["02"], 0.5)
    raw = render_frame(KITTI_2011_09_26["02"], frame_rng(5, index), scale=0.5)
    ideal = _blurred(render_ideal(KITTI_2011_09_26["02"], frame_rng(5, index), scale=0.5))

    def error(image: np.ndarray) -> float:
        return float(np.abs(_blurred(image) - ideal).mean())

    rectified = error(cv2.undistort(raw, calib.K, calib.D))
    assert rectified < 2.0  # grey levels, over the whole frame
    assert error(raw) > 4 * rectified  # the raw frame's lines are bowed
    wrong = calib.perturb(k1=0.1)
    assert error(cv2.undistort(raw, wrong.K, wrong.D)) > 1.5 * rectified  # a miscalibration shows


def test_impossible_distortion_is_an_error():
    with pytest.raises(AppdgenError, match="cannot be inverted"):
        render_frame(KITTI_2011_09_26["02"].replace(k1=-1.0, k2=0.0, k3=0.0), frame_rng(0, 0), scale=0.25)
