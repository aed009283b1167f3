"""Crop, maps and APPD against independent computations: a numpy lens model, brute force, laws of the metric."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import KITTI_2011_09_26, PAPER_RANGES

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd, appd_px
from appdgen.geometry.crop import check_output_size, search_region, slide_box, valid_region
from appdgen.geometry.maps import rectify


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
    # Height-limited: top and bottom edges touch the frame within 0.005 px, the sides have slack.
    assert top.min() == pytest.approx(0.0, abs=5e-3)
    assert bottom.max() == pytest.approx(kitti02.height - 1, abs=5e-3)
    assert left.min() > 1.0 and right.max() < kitti02.width - 2.0
    # Free to slide horizontally, it sits in the middle of the range of feasible positions.
    slack_left, slack_right = slide_distance(kitti02, crop, -1), slide_distance(kitti02, crop, +1)
    output_px = (crop.x1 - crop.x0) / kitti02.width
    assert slack_left > 50 * output_px
    assert abs(slack_left - slack_right) < 0.01 * output_px
    # ... which for this camera is nearly symmetric about the principal point.
    assert abs(crop.x0 + crop.x1) / 2 < 10 * output_px


def fits(calib: Calibration, crop) -> bool:
    """Whether the crop's border, densely sampled, maps inside the frame."""
    u, v = lens_pixels(*edge_points(crop), calib)
    return bool(u.min() >= 0 and v.min() >= 0 and u.max() <= calib.width - 1 and v.max() <= calib.height - 1)


def slide_distance(calib: Calibration, crop, direction: int) -> float:
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


def test_appd_does_not_depend_on_where_the_maps_lie_in_memory(kitti02):
    a, b = rectify(kitti02, (348, 128)), rectify(kitti02.perturb(fx=0.05, k1=0.1), (348, 128))

    def moved(array: np.ndarray, offset: int) -> np.ndarray:
        """A copy of a float32 array starting `offset` bytes past a 64-byte boundary."""
        raw = np.empty(array.nbytes + 128, np.uint8)
        start = (-raw.ctypes.data) % 64 + offset
        copy = raw[start:start + array.nbytes].view(np.float32).reshape(array.shape)
        copy[...] = array
        return copy

    values = {appd_px(a, type(b)(b.calib, b.crop, b.new_camera_matrix, moved(b.map_x, o), moved(b.map_y, 60 - o)))
              for o in range(0, 64, 4)}
    assert values == {appd_px(a, b)}  # to the last bit: builds must not depend on the worker


def test_search_region_is_the_nodes_crop_on_a_box_about_its_slide_box_or_none(kitti02):
    for calib in random_calibrations(kitti02, 20, seed=5):
        x0, x1, y0, y1 = slide_box(calib, 257)
        pad_x, pad_y = 0.15 * (x1 - x0), 0.15 * (y1 - y0)
        quick = search_region(calib, (x0 - pad_x, x1 + pad_x, y0 - pad_y, y1 + pad_y), 257)
        exact = valid_region(calib)
        px_per_unit = 1392 / (exact.x1 - exact.x0)
        assert max(abs(quick.x0 - exact.x0), abs(quick.x1 - exact.x1), abs(quick.y0 - exact.y0),
                   abs(quick.y1 - exact.y1)) * px_per_unit < 0.05  # output px: the search's estimate
        # A box that cuts the slide box (here: along the axis the crop slides) gives no crop rather than a wrong one.
        assert search_region(calib, (x0 - pad_x, x1 + pad_x, 0.5 * y0, 0.5 * y1), 257) is None


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


# --- every lens model: crop validity and maximality by brute force, APPD from independent projections -----------

from test_lens import CAMERAS, TUMVI, reference_pixels  # noqa: E402  (OpenCV / the papers' equations)

from appdgen.calib import formats  # noqa: E402
from appdgen.geometry.crop import fov_box  # noqa: E402
from appdgen.geometry.distortion import radial_fold_radius  # noqa: E402

MODEL_CASES = {**{name: (calib, None) for name, calib in CAMERAS.items() if name != "kb4"},
               "kb4-narrow": (TUMVI.replace(fx=2 * TUMVI.fx, fy=2 * TUMVI.fy), None), "kb4-tumvi-120": (TUMVI, 120.0)}


def reference_plane_pixels(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized points → raw pixels by the independent reference projection."""
    px = reference_pixels(np.stack([x.ravel(), y.ravel(), np.ones(x.size)], 1), calib)
    return px[:, 0].reshape(x.shape), px[:, 1].reshape(x.shape)


def valid_grid(calib: Calibration, xs: np.ndarray, ys: np.ndarray, max_fov: float | None) -> np.ndarray:
    """Brute-force validity on a grid: inside the frame, unfolded (positive Jacobian), in the model's plane domain."""
    gx, gy = np.meshgrid(xs, ys)
    u, v = reference_plane_pixels(gx, gy, calib)
    ux, vy = np.gradient(u, xs, axis=1), np.gradient(v, ys, axis=0)
    det = ux * vy - np.gradient(u, ys, axis=0) * np.gradient(v, xs, axis=1)
    ok = (u >= 0) & (u <= calib.width - 1) & (v >= 0) & (v <= calib.height - 1) & (ux > 0) & (vy > 0) & (det > 0)
    ok &= np.hypot(gx, gy) < radial_fold_radius(calib)
    if max_fov is not None:
        half_x, half_y = fov_box(calib, max_fov)
        ok &= (np.abs(gx) <= half_x) & (np.abs(gy) <= half_y)
    return ok


def fits_somewhere(ok: np.ndarray, cells_x: int, cells_y: int) -> bool:
    """Whether an all-valid block of cells_y × cells_x grid nodes exists (summed-area table)."""
    bad = np.pad(np.cumsum(np.cumsum(~ok, 0), 1), ((1, 0), (1, 0)))
    count = bad[cells_y:, cells_x:] - bad[:-cells_y, cells_x:] - bad[cells_y:, :-cells_x] + bad[:-cells_y, :-cells_x]
    return bool((count == 0).any())


def assert_crop_sound(calib: Calibration, max_fov: float | None) -> None:
    """valid_region's crop: border inside the frame to 0.001 px, unfolded, and maximal against brute force."""
    crop = valid_region(calib, max_fov=max_fov)
    u, v = reference_plane_pixels(*edge_points(crop, 4001), calib)
    assert u.min() >= -1e-3 and v.min() >= -1e-3
    assert u.max() <= calib.width - 1 + 1e-3 and v.max() <= calib.height - 1 + 1e-3
    if max_fov is not None:
        half_x, half_y = fov_box(calib, max_fov)
        assert max(-crop.x0, crop.x1) <= half_x * (1 + 1e-12) and max(-crop.y0, crop.y1) <= half_y * (1 + 1e-12)
    w, s = crop.x1 - crop.x0, crop.y1 - crop.y0
    step = s / 300
    xs = np.arange(crop.x0 - 0.25 * w, crop.x1 + 0.25 * w, step)
    ys = np.arange(crop.y0 - 0.25 * s, crop.y1 + 0.25 * s, step)
    ok = valid_grid(calib, xs, ys, max_fov)
    # Our rectangle (less the grid's resolution) is found, unfolded; nothing 1 % larger fits anywhere near.
    inner = (xs > crop.x0 + step) & (xs < crop.x1 - step), (ys > crop.y0 + step) & (ys < crop.y1 - step)
    assert ok[np.ix_(inner[1], inner[0])].all()
    assert fits_somewhere(ok, int(w / step) - 2, int(s / step) - 2)
    assert not fits_somewhere(ok, int(1.01 * w / step) + 1, int(1.01 * s / step) + 1)


@pytest.mark.parametrize("name", sorted(MODEL_CASES))
def test_crop_is_valid_and_maximal_for_every_model(name):
    assert_crop_sound(*MODEL_CASES[name])


def real_cameras(shared) -> list[tuple[str, Calibration]]:
    """Every camera of every calibration file in ../shared/data/formats."""
    found = []
    for path in sorted((shared / "formats").glob("*")):
        if path.suffix in (".yaml", ".yml", ".json", ".xml", ".txt"):
            found += [(f"{path.name}:{c}", formats.load(path, c)) for c in formats.list_cameras(path)]
    return found


def test_real_files_get_valid_maximal_crops(shared):
    cameras = real_cameras(shared)
    assert len(cameras) >= 10
    for name, calib in cameras:
        try:
            max_fov = None
            valid_region(calib)
        except AppdgenError as error:  # fisheyes that see past 90° inside the frame: TUM VI, T265
            assert "--max-fov" in str(error) and calib.model == "kb4", (name, error)
            max_fov = 120.0
        assert_crop_sound(calib, max_fov)


def test_kodak_wide_angle_gets_a_crop_past_its_folded_corners(shared):
    calib = formats.load(shared / "formats" / "ros_camera_info_kodak.yaml")
    crop = valid_region(calib)
    assert crop.x1 - crop.x0 > 3.5  # about 125° across


def test_fisheye_past_90_degrees_needs_max_fov():
    with pytest.raises(AppdgenError, match=r"^the kb4 lens sees 115° off-axis inside its 512x512 frame .*--max-fov"):
        valid_region(TUMVI)
    crop = valid_region(TUMVI, max_fov=120.0)
    half_x, half_y = fov_box(TUMVI, 120.0)
    assert crop.x1 == pytest.approx(half_x) and crop.x0 == pytest.approx(-half_x)
    assert half_x == pytest.approx(np.tan(np.radians(60)))
    with pytest.raises(AppdgenError, match="between 0 and 180"):
        valid_region(TUMVI, max_fov=180.0)


def independent_appd(a, b) -> float:
    """Mean raw-pixel distance of two rectifications' maps rebuilt from their K̂ by the reference projections."""
    maps = []
    for rect in (a, b):
        K, (w, h) = rect.new_camera_matrix, rect.size
        gx, gy = np.meshgrid((np.arange(w) - K[0, 2]) / K[0, 0], (np.arange(h) - K[1, 2]) / K[1, 1])
        maps.append(reference_plane_pixels(gx, gy, rect.calib))
    return float(np.hypot(maps[0][0] - maps[1][0], maps[0][1] - maps[1][1]).mean())


@pytest.mark.parametrize("name", sorted(MODEL_CASES))
def test_appd_matches_independent_projections_for_every_model(name):
    calib, max_fov = MODEL_CASES[name]
    other = calib.perturb(fx=0.02, cy=-0.01, **{calib.param_names[4]: 0.1})
    size = (calib.width // 4, calib.height // 4)
    a, b = rectify(calib, size, max_fov=max_fov), rectify(other, size, max_fov=max_fov)
    assert appd_px(a, b) == pytest.approx(independent_appd(a, b), abs=1e-3)
    assert appd(calib, calib, size, max_fov) == (0.0, 0.0)
    assert appd(calib, other, size, max_fov)[0] == appd(other, calib, size, max_fov)[0] > 0


def fit_ds(calib: Calibration, max_angle_deg: float = 75.0) -> Calibration:
    """A double sphere fitted to calib's projections by Gauss–Newton (numeric Jacobian) on rays up to max_angle."""
    rng = np.random.default_rng(0)
    theta, phi = np.radians(rng.uniform(0, max_angle_deg, 2000)), rng.uniform(0, 2 * np.pi, 2000)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    target = reference_pixels(rays, calib).ravel()

    def residual(p):
        ds = Calibration(*calib.size, *p[:4], model="ds", xi=p[4], alpha=p[5])
        return reference_pixels(rays, ds).ravel() - target

    p = np.array([calib.fx * 0.8, calib.fy * 0.8, calib.cx, calib.cy, -0.2, 0.6])
    for _ in range(30):
        r = residual(p)
        J = np.column_stack([(residual(p + d) - r) / 1e-7 for d in np.eye(6) * 1e-7])
        p = p - np.linalg.lstsq(J, r, rcond=None)[0]
    return Calibration(*calib.size, *p[:4], model="ds", xi=p[4], alpha=p[5])


def test_cross_model_appd_of_one_fisheye_is_small():
    ds = fit_ds(TUMVI)
    px, pct = appd(TUMVI, ds, (256, 256), max_fov=120.0)
    assert pct < 0.05  # the same lens in two models: a small fraction of a pixel
    # ... while a 1 % focal change of the same camera is far larger.
    assert appd(TUMVI, TUMVI.perturb(fx=0.01), (256, 256), max_fov=120.0)[1] > 10 * pct



def perturbed(calib: Calibration, n: int, seed: int) -> list[Calibration]:
    """n calibrations drawn uniformly (seeded) from the sampler's default ranges around calib."""
    from appdgen.sampling.ranges import default_ranges

    params, ranges = calib.params(), default_ranges(calib)
    bounds = {name: ranges[name].offsets(params[name]) for name in calib.param_names}
    rng = np.random.default_rng(seed)
    return [calib.replace(**{name: params[name] + rng.uniform(*bounds[name]) for name in calib.param_names})
            for _ in range(n)]


def property_cameras() -> list[tuple[str, Calibration, float | None]]:
    """Each lens model's test camera and, when ../shared/data is present, every camera of its real files."""
    from conftest import shared_data

    cameras = [(name, calib, max_fov) for name, (calib, max_fov) in sorted(MODEL_CASES.items())]
    if shared_data() is not None:
        cameras += [(name, calib, 120.0 if calib.model == "kb4" else None)  # fisheyes that see past 90°
                    for name, calib in real_cameras(shared_data())]
    return cameras


@pytest.mark.parametrize("name, calib, max_fov", property_cameras(), ids=lambda v: v if isinstance(v, str) else "")
def test_perturbed_crops_stay_in_the_frame_or_fold(name, calib, max_fov):
    """Random perturbations in the default ranges: a checked crop lies inside the frame to 0.001 px by OpenCV or
    the papers' projections, or it is refused in one line (the lens folds where the crop needs it, or its valid
    region is unbounded); never an internal error."""
    refused = 0
    for i, other in enumerate(perturbed(calib, 20, seed=len(name))):
        try:
            crop = valid_region(other, max_fov=max_fov)
        except AppdgenError as error:
            assert "internal error" not in str(error), (name, i, error)
            refused += 1
            continue
        u, v = reference_plane_pixels(*edge_points(crop, 2001), other)
        excess = max(-u.min(), -v.min(), u.max() - (other.width - 1), v.max() - (other.height - 1))
        assert excess <= 1e-3, (name, i, excess, other.to_dict())
    assert refused < 20, name
