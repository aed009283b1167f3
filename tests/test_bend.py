"""The label decomposed (geometry.bend): affine part and non-affine rest of the warp between two rectifications."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from appdgen.calib.calibration import Calibration
from appdgen.calib.defaults import default_calibration
from appdgen.geometry.bend import affine_rest, grid, split_warp, warp_field
from appdgen.geometry.crop import Crop, valid_region
from appdgen.geometry.distortion import distort_to_pixels, undistort_pixels
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler

KITTI = default_calibration()


def brute_bend(ref: Calibration, sample: Calibration, size: tuple[int, int], max_fov: float | None = None) -> float:
    """bend_px from OpenCV's full maps at an output size, without linearising: M̂m(p) − M̂*(A·p + t), raw px."""
    r, m = rectify(ref, size, max_fov=max_fov), rectify(sample, size, max_fov=max_fov)
    h, w = r.map_x.shape
    v, u = (a.astype(np.float64).ravel() for a in np.mgrid[0:h, 0:w])
    x, y = undistort_pixels(m.map_x.ravel(), m.map_y.ravel(), ref)
    k = r.new_camera_matrix
    design = np.column_stack([np.ones_like(u), u, v])
    au = design @ np.linalg.lstsq(design, k[0, 0] * x + k[0, 2], rcond=None)[0]
    av = design @ np.linalg.lstsq(design, k[1, 1] * y + k[1, 2], rcond=None)[0]
    # M̂* at A·p + t in closed form: the affine positions leave the reference image near its edges.
    at_u, at_v = distort_to_pixels((au - k[0, 2]) / k[0, 0], (av - k[1, 2]) / k[1, 1], ref)
    return float(np.hypot(m.map_x.ravel() - at_u, m.map_y.ravel() - at_v).mean())


def split(ref: Calibration, sample: Calibration, max_fov: float | None = None):
    """split_warp with both calibrations' own valid regions."""
    return split_warp(ref, valid_region(ref, max_fov=max_fov), sample, valid_region(sample, max_fov=max_fov))


def test_an_affine_warp_has_no_bend_and_its_shift_is_the_principal_point_change() -> None:
    # A distortion-free camera under one fixed crop: M̂m = Km·K̂⁻¹, so W is exactly affine.
    ref = Calibration(640, 480, 500.0, 500.0, 320.0, 240.0)
    crop = Crop(-0.4, -0.3, 0.4, 0.3)
    moved = ref.replace(cx=327.0, fx=510.0)
    s = split_warp(ref, crop, moved, crop)
    assert s.appd_grid_px > 5
    assert s.bend_px < 1e-9
    assert s.shift_x_px == pytest.approx(7.0, abs=1e-9) and s.shift_y_px == pytest.approx(0.0, abs=1e-9)
    assert s.scale == pytest.approx(np.sqrt(510.0 / 500.0), rel=1e-12)


def test_the_reference_against_itself_is_all_zero() -> None:
    s = split(KITTI, KITTI)
    assert s.bend_px < 1e-6 and abs(s.shift_x_px) < 1e-6 and abs(s.shift_y_px) < 1e-6
    assert s.scale == pytest.approx(1.0, abs=1e-9) and s.appd_grid_px < 1e-6


def test_a_principal_point_change_is_mostly_affine_and_k1_mostly_not() -> None:
    cx = split(KITTI, KITTI.replace(cx=KITTI.cx * 1.05))
    assert cx.bend_px < 0.25 * cx.appd_grid_px
    assert cx.shift_x_px < -0.9 * cx.appd_grid_px  # a larger cx moves the raw position left
    k1 = split(KITTI, KITTI.replace(k1=KITTI.k1 * 1.15))
    assert k1.bend_px > 0.5 * k1.appd_grid_px


def test_affine_rest_is_the_least_squares_affine_fits_residual() -> None:
    # Against a brute-force fit of both components at once (pseudo-inverse of the design), on scattered points of a
    # field that is affine plus a bend: the rest is orthogonal to 1, u and v, and an affine field leaves none.
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 1392, 500), rng.uniform(0, 512, 500)
    du, dv = 3.0 + 0.01 * u - 0.02 * v + 1e-6 * u * v, -1.0 + 0.03 * u + 2e-6 * (u - 700) ** 2
    fit = affine_rest(u, v, du, dv)
    design = np.column_stack([np.ones_like(u), u, v])
    coef = np.linalg.pinv(design) @ np.column_stack([du, dv])
    np.testing.assert_allclose(np.column_stack([fit.coef_u, fit.coef_v]), coef, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.column_stack([fit.rest_u, fit.rest_v]), np.column_stack([du, dv]) - design @ coef,
                               rtol=0, atol=1e-9)
    assert np.abs(design.T @ np.column_stack([fit.rest_u, fit.rest_v])).max() < 1e-6
    assert np.hypot(fit.rest_u, fit.rest_v).mean() > 0.1
    again = affine_rest(u, v, du, dv, design)  # a cached design gives the same bits
    assert all(np.array_equal(a, b) for a, b in zip(fit, again, strict=True))
    flat = affine_rest(u, v, 2.0 + 0.5 * u, 0.25 * v - 1.0)
    assert max(np.abs(flat.rest_u).max(), np.abs(flat.rest_v).max()) < 1e-9


def test_the_field_is_opencvs_map_difference_at_the_grid_points() -> None:
    sample = KITTI.replace(k1=KITTI.k1 * 1.1, cx=KITTI.cx + 9.0)
    r, m = rectify(KITTI, KITTI.size), rectify(sample, KITTI.size)
    field = warp_field(KITTI, r.crop, sample, m.crop, columns=12)
    u, v = (a.astype(np.float32).reshape(1, -1) for a in grid(KITTI, 12))
    at = [cv2.remap(mp, u, v, cv2.INTER_LINEAR).ravel() for mp in (m.map_x, m.map_y, r.map_x, r.map_y)]
    assert field.moved.shape == field.rest.shape == (12 * field.rows, 2) and field.rows == 4
    np.testing.assert_allclose(field.moved, np.column_stack([at[0] - at[2], at[1] - at[3]]), atol=0.02)
    s = split_warp(KITTI, r.crop, sample, m.crop, columns=12)
    assert np.hypot(*field.rest.T).mean() == pytest.approx(s.bend_px, rel=1e-12)
    assert np.hypot(*field.moved.T).mean() == pytest.approx(s.appd_grid_px, rel=1e-12)


@pytest.mark.parametrize("size", [(348, 128), (1392, 512)])
def test_the_split_matches_opencvs_maps_at_any_output_size(size: tuple[int, int]) -> None:
    for change in ({"k1": KITTI.k1 * 1.15}, {"k2": KITTI.k2 * 0.85, "fx": KITTI.fx * 1.1}):
        sample = KITTI.replace(**change)
        assert split(KITTI, sample).bend_px == pytest.approx(brute_bend(KITTI, sample, size), rel=2e-3)


def test_bend_never_exceeds_appd_by_more_than_the_fits_slack() -> None:
    sampler = Sampler(KITTI, appd_max=1.0)
    ref_crop = valid_region(KITTI)
    for i in range(12):
        draw = sampler.draw(7, i)
        s = split_warp(KITTI, ref_crop, draw.calib, valid_region(draw.calib))
        assert s.bend_px <= 1.05 * s.appd_grid_px + 1e-6, (i, s)
        assert s.appd_grid_px == pytest.approx(_full_appd(draw.calib), rel=2e-3, abs=1e-3)


def _full_appd(sample: Calibration) -> float:
    """APPD over the full raw-size output grid (raw px)."""
    from appdgen.geometry.appd import appd_px

    return appd_px(rectify(KITTI), rectify(sample))


@pytest.mark.parametrize("model, coeffs", [("kb4", (0.02, -0.01, 0.003, -0.0005)), ("ds", (-0.2, 0.6))])
def test_fisheye_models_split_as_well(model: str, coeffs: tuple[float, ...]) -> None:
    ref = Calibration(512, 512, 190.0, 190.0, 256.0, 256.0, model=model, coeffs=coeffs)
    sample = ref.replace(fx=200.0, fy=200.0)
    s = split(ref, sample, max_fov=120)
    assert 0 < s.bend_px <= 1.05 * s.appd_grid_px
    # 1.2 % here: a fisheye warp curves faster than the grid step
    assert s.bend_px == pytest.approx(brute_bend(ref, sample, (256, 256), max_fov=120), rel=0.02)
