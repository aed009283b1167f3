"""The classical floor (train.plumbline): plumb-line features of rectified images and their ridge fit."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from appdgen.calib.defaults import default_calibration
from appdgen.detect.edges import EdgePoints
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.bend import split_warp
from appdgen.geometry.crop import valid_region
from appdgen.geometry.distortion import undistort_pixels
from appdgen.geometry.maps import rectify
from appdgen.geometry.remap import remap_image
from appdgen.synth import scale_calibration
from studies import plumbline as floor_benchmark
from train.plumbline import (
    ALPHAS,
    FEATURE_NAMES,
    FEATURES,
    PlumbLine,
    bulges,
    edge_params,
    feature_matrix,
    line_features,
)

HALF = scale_calibration(default_calibration(), 0.5)  # KITTI at 696×256: lines bend by a pixel, render is quick
K1 = FEATURE_NAMES.index("radial_k1")
BEND = FEATURE_NAMES.index("radial_bend")


def straight_edges(width: int, height: int, seed: int) -> np.ndarray:
    """A grey canvas of overlapping filled bars at random angles: long straight edges of both polarities."""
    rng = np.random.default_rng(seed)
    image = np.full((height, width), 90, np.uint8)
    for _ in range(40):
        start = rng.uniform(-0.2, 1.2, 2) * (width, height)
        angle, length, thick = rng.uniform(0, np.pi), rng.uniform(0.2, 0.6) * width, rng.uniform(0.03, 0.2) * height
        along, across = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
        corners = np.array([start, start + length * along, start + length * along + thick * across,
                            start + thick * across])
        cv2.fillPoly(image, [np.round(corners * 16).astype(np.int32)], int(rng.integers(0, 256)), cv2.LINE_AA, 4)
    return image


def radial_warp(image: np.ndarray, k: float) -> np.ndarray:
    """The image seen through the field k·(x, y)·ρ² in centred coordinates of diagonal units (cubic remap)."""
    height, width = image.shape[:2]
    diagonal, cu, cv = math.hypot(width, height), (width - 1) / 2, (height - 1) / 2
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x, y = (u - cu) / diagonal, (v - cv) / diagonal
    grow = 1 + k * (x * x + y * y)
    map_x, map_y = (x * grow * diagonal + cu).astype(np.float32), (y * grow * diagonal + cv).astype(np.float32)
    return cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def raw_of(rectified: np.ndarray) -> np.ndarray:
    """The raw KITTI (HALF) frame whose reference rectification is `rectified`: each raw pixel takes the colour
    of its undistorted position in the reference output (K̂*·undistort(q; Θ*))."""
    k = valid_region(HALF).camera_matrix(HALF.size)
    v, u = np.mgrid[0:HALF.height, 0:HALF.width].astype(np.float64)
    x, y = undistort_pixels(u, v, HALF)
    return cv2.remap(rectified, (k[0, 0] * x + k[0, 2]).astype(np.float32), (k[1, 1] * y + k[1, 2]).astype(np.float32),
                     cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def k1_rectified(raw: np.ndarray, change: float) -> np.ndarray:
    """raw rectified with HALF's k1 changed by `change` (relative), on the reference crop."""
    return remap_image(raw, rectify(HALF.replace(k1=HALF.k1 * (1 + change)), HALF.size, valid_region(HALF)))


@pytest.mark.parametrize("image", [
    np.zeros((128, 348), np.uint8),
    np.full((128, 348, 3), 200, np.uint8),
    np.random.default_rng(0).integers(0, 256, (128, 348, 3), dtype=np.uint8),
    np.random.default_rng(1).integers(0, 256, (512, 1392), dtype=np.uint8),
    np.zeros((1, 1), np.uint8), np.zeros((7, 5, 3), np.uint8),
    np.random.default_rng(2).integers(0, 256, (16, 16), dtype=np.uint8),
    np.random.default_rng(3).integers(0, 256, (20, 300, 1), dtype=np.uint8),
], ids=["blank", "flat-bgr", "noise", "noise-large", "1x1", "tiny-bgr", "16x16", "one-channel"])
def test_features_are_finite_and_of_fixed_length(image: np.ndarray) -> None:
    features = line_features(image)
    assert features.shape == (FEATURES,) and features.dtype == np.float64
    assert np.isfinite(features).all()


def test_an_image_without_lines_has_zero_features() -> None:
    assert not line_features(np.zeros((128, 348), np.uint8)).any()
    assert not line_features(np.zeros((3, 3, 3), np.uint8)).any()


@pytest.mark.parametrize("image", [np.zeros((32, 32), np.float32), np.zeros((32, 32, 4), np.uint8),
                                   np.zeros((2, 32, 32), np.uint8)[..., None]])
def test_bad_images_are_refused_with_one_clear_error(image: np.ndarray) -> None:
    with pytest.raises(AppdgenError, match="plumb-line features need"):
        line_features(image)


def test_a_segments_bulge_is_read_off_its_edge_points_quadratic_away_from_the_centre() -> None:
    # One horizontal segment 100 px below the centre, its points on e = 0.2 + 1e-4·s² (s: −50…50 px, e along the
    # normal): the middle lies 1e-4·50² = 0.25 px from the chord. With the normal pointing away from the centre the
    # bulge is −0.25 px (the middle bows inwards); flipped towards the centre, the same edge reads +0.25 px.
    s = np.linspace(-50, 50, 21)
    e = 0.2 + 1e-4 * s ** 2
    for normal, bulge in ((1.0, -0.25), (-1.0, 0.25)):
        points = EdgePoints(s, 100 + normal * e, s, e, np.zeros(21, int), np.array([[0.0, normal]]),
                            np.array([[0.0, 100.0]]), np.array([100.0]), np.array([30.0]))
        seen = bulges(points, np.zeros(2))
        assert seen.bulge[0] == pytest.approx(bulge) and seen.half[0] == 50 and seen.distance[0] == 100
        assert seen.rms[0] < 1e-6


def test_edge_params_scale_the_evidence_to_the_image() -> None:
    full, quarter = edge_params(1392, 512), edge_params(348, 128)
    assert full.lsd_scale == pytest.approx(0.8 * 720 / 1392) and quarter.lsd_scale == 0.8
    assert full.min_len == pytest.approx(0.035 * math.hypot(1392, 512)) and quarter.min_len > 10
    assert full.step == 3.0 and quarter.step < 1.0  # a segment of the least length still holds ~16 points


def test_grey_and_bgr_give_the_same_features() -> None:
    grey = straight_edges(348, 128, 0)
    assert np.array_equal(line_features(grey), line_features(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)))


@pytest.mark.parametrize("size", [(696, 256), (1392, 512)])
def test_a_known_radial_field_is_measured(size: tuple[int, int]) -> None:
    canvas = straight_edges(*size, 0)
    assert abs(line_features(canvas)[K1]) < 0.02  # straight: no field
    for k in (-0.2, -0.1, 0.1, 0.2):
        measured = line_features(radial_warp(canvas, k))[K1]
        assert measured == pytest.approx(k, abs=0.03 + 0.15 * abs(k)), (size, k)


def test_straight_lines_through_the_kitti_lens_straighten_and_bend_more_with_k1() -> None:
    """A canvas of straight edges as the reference rectification shows it, made raw through KITTI's lens: rectified
    with the reference it is straight again; with k1 changed by 5, 10, 15 %, either way, it bends more and more, in
    proportion to the label's own bend (geometry.bend; measured 1.30-1.58 × bend_pct: output vs raw diagonal)."""
    raw = raw_of(cv2.cvtColor(straight_edges(*HALF.size, 1), cv2.COLOR_GRAY2BGR))
    crop = valid_region(HALF)
    straight = line_features(k1_rectified(raw, 0.0))
    ratios = []
    for sign in (-1, 1):
        changes = [sign * c for c in (0.05, 0.10, 0.15)]
        bends = [line_features(k1_rectified(raw, c))[BEND] for c in changes]
        assert bends[0] < bends[1] < bends[2], (sign, bends)
        assert straight[BEND] < 0.25 * bends[0], (straight[BEND], bends)
        labels = [px_to_pct(split_warp(HALF, crop, HALF.replace(k1=HALF.k1 * (1 + c)), crop).bend_px, HALF)
                  for c in changes]
        ratios += [b / label for b, label in zip(bends, labels, strict=True)]
    assert max(ratios) < 1.5 * min(ratios), ratios


@pytest.mark.slow
def test_a_ridge_fit_on_some_streets_ranks_the_bend_of_unseen_ones() -> None:
    """30 streets × 2 fresh calibrations at 696×256, each street's pairs predicted by a fit on the other streets
    (5 folds). Measured: Spearman ρ 0.48, MAE 0.92 × the mean predictor's (seeds 1, 2: 0.60 / 0.74, 0.49 / 0.80;
    the scenes, not the calibrations, set the noise)."""
    images, targets = floor_benchmark.pairs(30, 0.5, 0, draws=2)
    x = feature_matrix(images)
    ratio, rho, _ = floor_benchmark.score(x, targets["bend_pct"], 1.0, folds=5, draws=2)
    assert rho > 0.25 and ratio < 1.0, (rho, ratio)
    model = PlumbLine().fit(images[:30], targets["bend_pct"][:30])
    assert np.array_equal(model.predict(images[30:]), model.predict_features(x[30:]))
    assert np.array_equal(model.weights, PlumbLine().fit_features(x[:30], targets["bend_pct"][:30]).weights)


def test_ridge_recovers_a_linear_law_and_round_trips_through_json(tmp_path) -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (200, FEATURES)) * np.arange(1, FEATURES + 1)  # no tail for the ±3σ clip to cut
    y = 2.0 + x @ np.linspace(0.1, 0.3, FEATURES)
    model = PlumbLine().fit_features(x, y, alpha=1e-6)
    assert np.allclose(model.predict_features(x), np.maximum(y, 0), atol=1e-4)
    path = tmp_path / "floor.json"
    model.save(path)
    json.loads(path.read_text())  # plain JSON
    again = PlumbLine.load(path)
    assert np.array_equal(again.predict_features(x), model.predict_features(x))
    assert PlumbLine.from_dict(model.to_dict()).alpha == model.alpha


def test_predictions_are_clipped_at_zero_and_alpha_none_cross_validates() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(60, FEATURES))
    y = x[:, 0] - 1.0  # half of it negative
    model = PlumbLine().fit_features(x, y, alpha=None)
    assert model.alpha in ALPHAS
    assert (model.predict_features(x) >= 0).all() and (model.predict_features(x) == 0).any()


def test_misuse_is_a_clear_error(tmp_path) -> None:
    with pytest.raises(AppdgenError, match="before fit"):
        PlumbLine().predict_features(np.zeros((1, FEATURES)))
    with pytest.raises(AppdgenError, match="features for"):
        PlumbLine().fit_features(np.zeros((5, FEATURES + 1)), np.zeros(5))
    with pytest.raises(AppdgenError, match="not a plumb-line detector"):
        PlumbLine.from_dict({"format": "something else"})
    saved = PlumbLine().fit_features(np.random.default_rng(2).normal(size=(10, FEATURES)), np.arange(10.0)).to_dict()
    with pytest.raises(AppdgenError, match=f"{FEATURES} numbers each"):
        PlumbLine.from_dict({**saved, "weights": saved["weights"][:-1]})
    with pytest.raises(AppdgenError, match="bad field"):
        PlumbLine.from_dict({k: v for k, v in saved.items() if k != "alpha"})
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(AppdgenError, match="bad.json"):
        PlumbLine.load(tmp_path / "bad.json")


def test_the_module_imports_without_torch() -> None:
    code = "import sys; sys.modules['torch'] = None; import train.plumbline as p; print(p.FEATURES)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) == FEATURES
