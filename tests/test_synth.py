"""Procedural raw frames: determinism, sizes, and that Θ's rectification straightens them again."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from conftest import KITTI_2011_09_26

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import load
from appdgen.errors import AppdgenError
from appdgen.geometry.distortion import pixel_rays
from appdgen.synth import (
    _lens_maps,
    frame_rng,
    render_frame,
    render_ideal,
    scale_calibration,
    synthesize,
)
from appdgen.synth.cubemap import CubeMaps
from appdgen.synth.street import CAR, LOOSE, Street, random_street
from helpers import run_cli

#: TUM VI cam0 as Kalibr's pinhole-equi (Kannala–Brandt) calibration publishes it: 512x512, ~190° across.
TUMVI_KB4 = Calibration(512, 512, 190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504,
                        model="kb4", k1=0.0034823894022493434, k2=0.0007150348452162257, k3=-0.0020532361418706202,
                        k4=0.00020293673591811182)
#: A wide double-sphere lens (TUM VI's ξ, α, shorter focal length) whose image circle ends inside the frame.
WIDE_DS = Calibration(128, 128, 30.0, 30.0, 63.6, 64.1, model="ds", xi=-0.17, alpha=0.59)


def test_scale_calibration():
    full = KITTI_2011_09_26["02"]
    small = scale_calibration(full, 0.25)
    assert small.size == (348, 128)
    np.testing.assert_allclose([small.fx, small.fy], [full.fx * 0.25, full.fy * 0.25])
    np.testing.assert_array_equal(small.D, full.D)
    assert scale_calibration(full, 1.0) is full
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(AppdgenError, match="scale"):
            scale_calibration(full, bad)


@pytest.mark.parametrize("calib", [TUMVI_KB4, WIDE_DS])
def test_scale_calibration_keeps_any_model(calib):
    scaled = scale_calibration(calib, 0.5)
    assert (scaled.model, scaled.coeffs) == (calib.model, calib.coeffs)
    assert scaled.size == (calib.width // 2, calib.height // 2) and scaled.fx == calib.fx / 2


def test_scale_calibration_keeps_pixel_centres_at_integers():
    # A principal point at the image centre ((W - 1) / 2 with pixel centres at integers) stays at the centre.
    centred = KITTI_2011_09_26["02"].replace(cx=(1392 - 1) / 2, cy=(512 - 1) / 2)
    for s in (0.25, 0.5, 2.0):
        scaled = scale_calibration(centred, s)
        assert (scaled.cx, scaled.cy) == pytest.approx(((scaled.width - 1) / 2, (scaled.height - 1) / 2))
    # A ray hitting pixel u of the full camera hits the same place of the scaled sensor: pixel edges scale, so
    # u' + 0.5 = (u + 0.5)·s (x/z = 0.1, 0.2 in the ideal image).
    full = KITTI_2011_09_26["02"]
    small = scale_calibration(full, 0.25)
    u, v = full.fx * 0.1 + full.cx, full.fy * 0.2 + full.cy
    assert small.fx * 0.1 + small.cx == pytest.approx((u + 0.5) * 0.25 - 0.5)
    assert small.fy * 0.2 + small.cy == pytest.approx((v + 0.5) * 0.25 - 0.5)


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
    np.testing.assert_array_equal(cv2.imread(str(paths[2])),
                                  render_frame(KITTI_2011_09_26["02"], frame_rng(9, 2), scale=0.25))
    assert synthesize(KITTI_2011_09_26["02"], 0, tmp_path / "c", seed=9) == []
    with pytest.raises(AppdgenError, match="frames"):
        synthesize(KITTI_2011_09_26["02"], -1, tmp_path / "d", seed=9)


def test_canvas_holds_every_sample():
    map_x, map_y, K, (w, h) = _lens_maps(KITTI_2011_09_26["02"])  # one canvas, not a cube
    assert map_x.min() >= 2 and map_y.min() >= 2 and map_x.max() <= w - 3 and map_y.max() <= h - 3
    # barrel distortion: the undistorted view is wider
    assert w > KITTI_2011_09_26["02"].width and h > KITTI_2011_09_26["02"].height


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


@pytest.mark.parametrize("calib, scale, wrong", [
    (TUMVI_KB4, 0.25, {"k1": 0.1}),  # k1 ± 0.1: a TUM VI-sized error
    (WIDE_DS, 1.0, {"alpha": -0.15}),
])
def test_rectifying_a_fisheye_with_theta_gives_the_ideal_pinhole_image(calib, scale, wrong):
    # Rectified to a pinhole with the camera's own K (a ~106° or 130° view), the fisheye frame drawn on cube
    # faces matches the scene drawn straight onto one pinhole canvas; the wrong lens does not.
    small = scale_calibration(calib, scale)
    assert isinstance(_lens_maps(small), CubeMaps)  # rays past 90°: the cube path
    raw = render_frame(calib, frame_rng(5, 0), scale=scale)
    ideal = _blurred(render_ideal(calib, frame_rng(5, 0), scale=scale))

    def error(theta: Calibration) -> float:
        maps = lens.get(theta.model).maps(theta.K, theta.coeffs, small.K, small.size)
        return float(np.abs(_blurred(cv2.remap(raw, *maps, cv2.INTER_LINEAR)) - ideal).mean())

    rectified = error(small)
    assert rectified < 4.0  # grey levels, over the whole frame
    assert float(np.abs(_blurred(raw) - ideal).mean()) > 2.5 * rectified  # the fisheye bends the view
    assert error(small.replace(**{k: getattr(small, k) + d for k, d in wrong.items()})) > 1.5 * rectified


def test_pixels_outside_the_image_circle_are_black():
    X, _, _ = pixel_rays(*np.meshgrid(np.arange(128.0), np.arange(128.0)), WIDE_DS)
    dark = np.isnan(X)
    assert 0.05 < dark.mean() < 0.3  # the corners: no ray reaches them
    for index in range(2):
        frame = render_frame(WIDE_DS, frame_rng(2, index))
        assert np.all(frame[dark] == 0)
        assert np.all(frame[~dark].max(axis=-1) > 0)  # lit, however dark the asphalt


def test_a_fisheye_sees_sideways_and_up():
    # A 190° lens on a cube: five faces (not the back one), and the rays past 90° see buildings and sky.
    maps = _lens_maps(scale_calibration(TUMVI_KB4, 0.25))
    assert maps.faces == (0, 1, 2, 3, 4)
    frame = render_frame(TUMVI_KB4, frame_rng(3, 0), scale=0.25)
    for edge in (frame[:, :4], frame[:, -4:], frame[:4]):  # left, right, top: 100°-115° off-axis
        assert edge.std() > 10


def test_fisheye_jobs_give_the_same_bytes(tmp_path):
    one = synthesize(TUMVI_KB4, 3, tmp_path / "one", seed=4, scale=0.2, jobs=1)
    two = synthesize(TUMVI_KB4, 3, tmp_path / "two", seed=4, scale=0.2, jobs=2)
    assert [p.read_bytes() for p in two] == [p.read_bytes() for p in one]


@pytest.mark.parametrize("calib, name", [(TUMVI_KB4, "calibration.yaml"), (WIDE_DS, "calibration.json")])
def test_synth_command_writes_a_calibration_of_any_model(tmp_path, calib, name):
    from appdgen.calib.formats import save

    source = tmp_path / "lens.json"
    save(calib, source)
    result = run_cli(["synth", "--calib", str(source), "--frames", "1", "--scale", "0.25", "--out",
                      str(tmp_path / "raw"), "--jobs", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    assert f"and {name} to" in result.output
    scaled = scale_calibration(calib, 0.25)
    assert load(tmp_path / "raw" / name) == scaled
    assert cv2.imread(str(tmp_path / "raw" / "frame_000000.png")).shape == (scaled.height, scaled.width, 3)


def test_synth_jobs_follow_builds_joblib_rule(tmp_path):
    result = run_cli(["synth", "--frames", "1", "--scale", "0.1", "--out", str(tmp_path / "zero"), "--jobs", "0"])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and "--jobs 0" in result.output
    assert not (tmp_path / "zero").exists()
    result = run_cli(["synth", "--frames", "2", "--scale", "0.1", "--out", str(tmp_path / "all"), "--jobs", "-1",
                      "--quiet"])
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "all").glob("frame_*.png"))) == 2


def test_impossible_distortion_is_an_error():
    with pytest.raises(AppdgenError, match="cannot be inverted"):
        render_frame(KITTI_2011_09_26["02"].replace(k1=-1.0, k2=0.0, k3=0.0), frame_rng(0, 0), scale=0.25)


def test_jobs_give_the_same_bytes(tmp_path):
    calib = KITTI_2011_09_26["02"]
    one = synthesize(calib, 5, tmp_path / "one", seed=4, scale=0.1, jobs=1)
    calls = []
    two = synthesize(calib, 5, tmp_path / "two", seed=4, scale=0.1, jobs=2, progress=calls.append)
    assert [p.name for p in two] == [p.name for p in one]
    assert [p.read_bytes() for p in two] == [p.read_bytes() for p in one]
    assert sum(calls) == 5


def _pose(camera) -> tuple[float, float, float, float]:
    """(yaw, pitch, roll) in radians of the camera's optical axis and x axis in the world, and its height (m)."""
    axis, right = camera.R[2], camera.R[0]  # rows of world→camera R: the camera's z and x axes in world terms
    pitch = np.arcsin(axis[1])
    return np.arctan2(axis[0], axis[2]), pitch, np.arcsin(-right[1] / np.cos(pitch)), -camera.C[1]


@pytest.mark.parametrize("mount", [CAR, LOOSE])
def test_mount_bounds_the_pose(mount):
    poses = np.array([_pose(Street(frame_rng(5, i), mount).camera) for i in range(400)])
    yaw, pitch, roll, height = poses.T
    assert np.abs(yaw).max() <= mount.yaw_max + 1e-12 and np.std(yaw) == pytest.approx(mount.yaw, rel=0.2)
    assert np.abs(pitch).max() <= mount.pitch and np.abs(pitch).max() > 0.9 * mount.pitch
    assert np.abs(roll).max() <= mount.roll and np.abs(roll).max() > 0.9 * mount.roll
    assert np.abs(height - mount.height).max() <= mount.height_jitter


def test_car_mount_keeps_the_vanishing_point_within_the_principal_point_range():
    # Where the street's vanishing direction (0, 0, 1) lands: spread well below ±5 % of cx, cy (paper range).
    calib = KITTI_2011_09_26["02"]
    spots = []
    for i in range(300):
        d = Street(frame_rng(6, i), CAR).camera.R @ [0.0, 0.0, 1.0]
        spots.append((calib.fx * d[0] / d[2] + calib.cx, calib.fy * d[1] / d[2] + calib.cy))
    spread = np.abs(np.array(spots) - [calib.cx, calib.cy]).max(axis=0)
    assert spread[0] < 0.05 * calib.cx and spread[1] < 0.05 * calib.cy


def test_mount_changes_the_pose_only():
    car, loose = random_street(frame_rng(7, 0), CAR), random_street(frame_rng(7, 0), LOOSE)
    assert len(car.groups) == len(loose.groups) and car.noise_seed == loose.noise_seed
    assert not np.allclose(car.camera.R, loose.camera.R)


def test_offset_moves_the_camera_sideways_in_the_same_street():
    still = random_street(frame_rng(7, 0), CAR)
    moved = random_street(frame_rng(7, 0), dataclasses.replace(CAR, offset=0.3))
    np.testing.assert_allclose(moved.camera.R, still.camera.R)
    step = moved.camera.C - still.camera.C
    # 0.3 m along the camera's own x axis (its first row of world→camera R), nothing else moved
    assert np.linalg.norm(step) == pytest.approx(0.3) and still.camera.R[0] @ step == pytest.approx(0.3)
    assert len(moved.groups) == len(still.groups) and moved.noise_seed == still.noise_seed
    for (box_a, _), (box_b, _) in zip(still.groups, moved.groups, strict=True):
        np.testing.assert_array_equal(box_a, box_b)  # the same world drawn


def test_offset_frame_is_the_same_street_seen_from_the_side():
    calib = KITTI_2011_09_26["02"]
    a = render_frame(calib, frame_rng(3, 0), 0.1)
    b = render_frame(calib, frame_rng(3, 0), 0.1, dataclasses.replace(CAR, offset=0.0))
    c = render_frame(calib, frame_rng(3, 0), 0.1, dataclasses.replace(CAR, offset=0.5))
    np.testing.assert_array_equal(a, b)  # offset 0 is the default frame, byte for byte
    assert np.abs(a.astype(int) - c).mean() > 1.0  # moved: the picture changes ...
    # ... but it is the same street: same sky and light, so the colour statistics barely move
    assert np.abs(a.reshape(-1, 3).mean(0) - c.reshape(-1, 3).mean(0)).max() < 8.0


def test_synth_offset_option_renders_the_moved_camera(tmp_path):
    result = run_cli(["synth", "--frames", "1", "--scale", "0.1", "--seed", "4", "--offset", "0.4", "--out",
                      str(tmp_path / "moved"), "--quiet"])
    assert result.exit_code == 0, result.output
    written = cv2.imread(str(tmp_path / "moved" / "frame_000000.png"))
    expected = render_frame(KITTI_2011_09_26["02"], frame_rng(4, 0), 0.1, dataclasses.replace(CAR, offset=0.4))
    np.testing.assert_array_equal(written, expected)
