"""Crop, maps and APPD against independent computations: a numpy lens model, brute force, laws of the metric."""
from __future__ import annotations

import numpy as np
import pytest

from appdgen.appd import appd, appd_px
from appdgen.calibration import Calibration
from appdgen.crop import check_output_size, valid_region
from appdgen.errors import AppdgenError
from appdgen.maps import rectify
from conftest import KITTI_2011_09_26, PAPER_RANGES


def lens_pixels(x: np.ndarray, y: np.ndarray, c: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Independent radial-tangential model (written here, not imported): normalized → raw pixels."""
    r2 = x**2 + y**2
    radial = 1 + c.k1 * r2 + c.k2 * r2**2 + c.k3 * r2**3
    xd = x * radial + 2 * c.p1 * x * y + c.p2 * (r2 + 2 * x**2)
    yd = y * radial + c.p1 * (r2 + 2 * y**2) + 2 * c.p2 * x * y
    return c.fx * xd + c.cx, c.fy * yd + c.cy


def random_calibrations(reference: Calibration, n: int, seed: int) -> list[Calibration]:
    """n calibrations drawn uniformly in the paper's ranges around a reference."""
    rng = np.random.default_rng(seed)
    return [reference.perturb(**{k: rng.uniform(*r) for k, r in PAPER_RANGES.items()}) for _ in range(n)]


def edge_points(crop, n: int = 20001) -> tuple[np.ndarray, np.ndarray]:
    """Dense points along the border of a crop rectangle (normalized)."""
    t = np.linspace(0.0, 1.0, n)
    xs, ys = crop.x0 + t * (crop.x1 - crop.x0), crop.y0 + t * (crop.y1 - crop.y0)
    x = np.concatenate([xs, xs, np.full(n, crop.x0), np.full(n, crop.x1)])
    y = np.concatenate([np.full(n, crop.y0), np.full(n, crop.y1), ys, ys])
    return x, y


@pytest.mark.parametrize("camera", sorted(KITTI_2011_09_26))
@pytest.mark.parametrize("size", [(1392, 512), (348, 128)])
def test_maps_match_numpy_lens_model(camera, size):
    calib = KITTI_2011_09_26[camera]
    rect = rectify(calib, size)
    K = rect.new_camera_matrix
    u, v = np.meshgrid(np.arange(size[0], dtype=float), np.arange(size[1], dtype=float))
    mx, my = lens_pixels((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], calib)
    assert rect.map_x.shape == (size[1], size[0]) and rect.map_x.dtype == np.float32
    assert np.abs(rect.map_x - mx).max() <= 1e-3
    assert np.abs(rect.map_y - my).max() <= 1e-3


def test_output_pixels_cover_the_crop_exactly(kitti02):
    crop = valid_region(kitti02)
    K = crop.camera_matrix((1392, 512))
    # Pixel edges −0.5 and w−0.5 land on R's sides: the same R serves any output size of the raw aspect.
    assert (-0.5 - K[0, 2]) / K[0, 0] == pytest.approx(crop.x0, abs=1e-12)
    assert (1391.5 - K[0, 2]) / K[0, 0] == pytest.approx(crop.x1, abs=1e-12)
    assert (511.5 - K[1, 2]) / K[1, 1] == pytest.approx(crop.y1, abs=1e-12)
    # Raw aspect in pixels: the output pixels are as square as the raw ones.
    assert K[0, 0] / K[1, 1] == pytest.approx(kitti02.fx / kitti02.fy, rel=1e-9)


def test_kitti02_crop_is_height_limited_and_centred(kitti02):
    crop = valid_region(kitti02)
    x, y = edge_points(crop)
    u, v = lens_pixels(x, y, kitti02)
    top, bottom = v[:20001], v[20001:40002]
    left, right = u[40002:60003], u[60003:]
    # Height-limited: top and bottom edges touch the frame within 0.005 px, the sides have room to spare.
    assert top.min() == pytest.approx(0.0, abs=5e-3)
    assert bottom.max() == pytest.approx(kitti02.height - 1, abs=5e-3)
    assert left.min() > 1.0 and right.max() < kitti02.width - 2.0
    # Free to slide horizontally, it sits in the middle of the range of feasible positions.
    room_left, room_right = slide_room(kitti02, crop, -1), slide_room(kitti02, crop, +1)
    output_px = (crop.x1 - crop.x0) / kitti02.width
    assert room_left > 50 * output_px
    assert abs(room_left - room_right) < 0.01 * output_px
    # ... which for this camera is nearly symmetric about the principal point.
    assert abs(crop.x0 + crop.x1) / 2 < 10 * output_px


def fits(calib: Calibration, crop) -> bool:
    """Whether the crop's border, densely sampled, maps inside the frame."""
    u, v = lens_pixels(*edge_points(crop), calib)
    return bool(u.min() >= 0 and v.min() >= 0 and u.max() <= calib.width - 1 and v.max() <= calib.height - 1)


def slide_room(calib: Calibration, crop, direction: int) -> float:
    """How far (normalized) the crop slides sideways and stays valid, by bisection (1e-6 shaved off vertically)."""
    lo, hi = 0.0, 0.5
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        moved = type(crop)(crop.x0 + direction * mid, crop.y0 + 1e-6, crop.x1 + direction * mid, crop.y1 - 1e-6)
        lo, hi = (mid, hi) if fits(calib, moved) else (lo, mid)
    return lo


@pytest.mark.parametrize("camera", sorted(KITTI_2011_09_26))
def test_no_invalid_pixel_over_1000_random_calibrations(camera):
    worst = np.inf
    for calib in random_calibrations(KITTI_2011_09_26[camera], 1000, seed=int(camera)):
        rect = rectify(calib)
        lo = min(rect.map_x.min(), rect.map_y.min())
        hi_x, hi_y = rect.map_x.max() - (calib.width - 1), rect.map_y.max() - (calib.height - 1)
        worst = min(worst, lo, -hi_x, -hi_y)
        assert lo >= 0 and hi_x <= 0 and hi_y <= 0, calib
    # Pixel centres sit half an output pixel inside R, so the margin is strictly positive.
    assert worst > 0.1


def brute_force_fits(calib: Calibration, crop, height: float, step: float) -> bool:
    """Whether a rectangle of this normalized height (raw aspect) fits in the valid set, searched on a grid."""
    aspect = calib.width / calib.height * calib.fy / calib.fx
    xs = np.arange(crop.x0 - 0.2, crop.x1 + 0.2, step)
    ys = np.arange(crop.y0 - 0.1, crop.y1 + 0.1, step)
    gx, gy = np.meshgrid(xs, ys)
    u, v = lens_pixels(gx, gy, calib)
    ok = (u >= 0) & (u <= calib.width - 1) & (v >= 0) & (v <= calib.height - 1) & (np.hypot(gx, gy) < 1.1)
    bad = np.pad(np.cumsum(np.cumsum(~ok, 0), 1), ((1, 0), (1, 0)))
    ny, nx = int(np.ceil(height / step)) + 1, int(np.ceil(aspect * height / step)) + 1
    count = bad[ny:, nx:] - bad[:-ny, nx:] - bad[ny:, :-nx] + bad[:-ny, :-nx]
    return bool((count == 0).any())


@pytest.mark.parametrize("index", range(6))
def test_crop_is_maximal_by_brute_force(index):
    calib = random_calibrations(KITTI_2011_09_26["02"], 6, seed=7)[index] if index else KITTI_2011_09_26["02"]
    crop = valid_region(calib)
    s, step = crop.y1 - crop.y0, 5e-4  # grid step ≈ 0.5 raw pixel
    # The brute force finds our size (less the grid's resolution) but nothing larger than it.
    assert brute_force_fits(calib, crop, s - 2 * step, step)
    assert not brute_force_fits(calib, crop, s + 2 * step, step)
    # Our rectangle is valid everywhere on its border, sampled ~0.001 px apart.
    u, v = lens_pixels(*edge_points(crop), calib)
    assert u.min() >= -1e-3 and v.min() >= -1e-3
    assert u.max() <= calib.width - 1 + 1e-3 and v.max() <= calib.height - 1 + 1e-3


def test_crop_touches_the_frame_within_a_hundredth_of_a_pixel():
    for calib in random_calibrations(KITTI_2011_09_26["03"], 40, seed=3):
        crop = valid_region(calib)
        u, v = lens_pixels(*edge_points(crop), calib)
        n = len(u) // 4
        vertical = max(-v[:n].min(), v[n:2 * n].max() - (calib.height - 1))
        horizontal = max(-u[2 * n:3 * n].min(), u[3 * n:].max() - (calib.width - 1))
        # Some pair of opposite sides is tight: R cannot grow by 0.01 px without leaving the frame.
        tight_v = abs(v[:n].min()) < 0.01 and abs(v[n:2 * n].max() - (calib.height - 1)) < 0.01
        tight_h = abs(u[2 * n:3 * n].min()) < 0.01 and abs(u[3 * n:].max() - (calib.width - 1)) < 0.01
        assert vertical <= 1e-3 and horizontal <= 1e-3
        assert tight_v or tight_h or _tight_corner(calib, crop)


def _tight_corner(calib: Calibration, crop) -> bool:
    """Whether growing R by 0.01 output px about its centre leaves the frame (corner-limited crops)."""
    grow = 0.01 / calib.height * (crop.y1 - crop.y0)
    bigger = type(crop)(crop.x0 - grow, crop.y0 - grow, crop.x1 + grow, crop.y1 + grow)
    u, v = lens_pixels(*edge_points(bigger), calib)
    return bool(u.min() < 0 or v.min() < 0 or u.max() > calib.width - 1 or v.max() > calib.height - 1)


def test_appd_is_zero_on_itself_and_symmetric():
    calibs = random_calibrations(KITTI_2011_09_26["02"], 5, seed=11)
    for a in calibs:
        assert appd(a, a) == (0.0, 0.0)
        for b in calibs:
            assert appd(a, b)[0] == appd(b, a)[0]


def test_appd_matches_float64_mean_distance(kitti02):
    other = kitti02.perturb(fx=0.03, cy=-0.02, k1=0.1)
    a, b = rectify(kitti02), rectify(other)
    expected = np.hypot(a.map_x.astype(float) - b.map_x, a.map_y.astype(float) - b.map_y).mean()
    assert appd_px(a, b) == pytest.approx(expected, rel=1e-6)
    px, pct = appd(kitti02, other)
    assert pct == pytest.approx(px * 100 / np.hypot(1392, 512), rel=1e-12)


def test_appd_grows_smoothly_and_monotonically_in_fx(kitti02):
    ref = rectify(kitti02)
    for sign in (1, -1):
        t = sign * np.linspace(0.0001, 0.02, 200)
        values = np.array([appd_px(ref, rectify(kitti02.perturb(fx=ti))) for ti in t])
        first = np.diff(values)
        second = np.diff(values, 2)
        assert (first > 0).all()
        # No quantization noise: curvature steps are tiny next to the values themselves.
        assert np.abs(second).max() < 1e-3 * values.max()
        assert np.abs(second).max() < 0.05 * np.abs(first).min()


@pytest.mark.parametrize("k1", [-0.5, -1.0, -3.0])
def test_fold_over_is_rejected_with_the_parameters(kitti02, k1):
    # Without k2, k3 the radial factor r(1 + k1 r²) stops growing inside the frame where R would reach.
    with pytest.raises(AppdgenError, match=rf"folds over.*k1={k1:g} k2=0"):
        valid_region(kitti02.replace(k1=k1, k2=0.0, k3=0.0))


def test_output_size_must_keep_the_raw_aspect(kitti02):
    assert check_output_size(kitti02, (700, 257)) == (700, 257)
    with pytest.raises(AppdgenError, match="aspect"):
        check_output_size(kitti02, (700, 300))
    with pytest.raises(AppdgenError, match="positive"):
        check_output_size(kitti02, (0, 0))
