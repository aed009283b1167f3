"""The lens models against OpenCV (radtan, rational, kb4) and against their papers' equations (DS, EUCM).

The reference projections here are written independently of appdgen.lens: OpenCV's projectPoints, and the
double sphere (Usenko, Demmel, Cremers 2018, eq. 40–47) and EUCM (Khomutenko, Garcia, Martinet 2016, eq. 9–10)
formulas for a 3-D point, with their closed-form inverses.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import KITTI_2011_09_26

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.distortion import pixel_rays, project, undistort_pixels
from appdgen.lens import numerics

# Published values: the 2880x1860 ROS rational_polynomial file, TUM VI cam0 (Kalibr pinhole-equi), EuRoC cam0
# (Basalt eucm); DS values are Usenko et al.'s fit of an EuRoC-like lens, thin prism terms made up and small.
RATIONAL_8 = Calibration(2880, 1860, 1495.316895, 1494.778564, 1424.459106, 943.463684, 0.929988205433,
                         0.165922805667, -0.000024369263, -0.000013859207, 0.002885974478, 1.331432461739,
                         0.435830116272, 0.027607271448, model="rational")
RATIONAL_12 = RATIONAL_8.replace(s1=0.0012, s2=-0.0004, s3=-0.0009, s4=0.0003)
TUMVI = Calibration(512, 512, 190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504,
                    0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182,
                    model="kb4")
EUROC_EUCM = Calibration(752, 480, 460.76484651566466, 459.4051018049483, 365.8937161309615, 249.33499869752444,
                         model="eucm", alpha=0.5903365915227143, beta=1.127468196965374)
DS = Calibration(752, 480, 349.7, 348.9, 365.9, 249.3, model="ds", xi=-0.2, alpha=0.59)
CAMERAS = {"radtan": KITTI_2011_09_26["02"], "rational8": RATIONAL_8, "rational12": RATIONAL_12, "kb4": TUMVI,
           "ds": DS, "eucm": EUROC_EUCM}


def ds_paper(P: np.ndarray, xi: float, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Double sphere projection of 3-D points (…, 3) to normalized (mx, my), Usenko et al. eq. 40–45."""
    x, y, z = P[..., 0], P[..., 1], P[..., 2]
    d1 = np.sqrt(x**2 + y**2 + z**2)
    d2 = np.sqrt(x**2 + y**2 + (xi * d1 + z) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + z)
    return x / den, y / den


def ds_paper_valid(P: np.ndarray, xi: float, alpha: float) -> np.ndarray:
    """The double sphere's projection domain z > −w2·d1 (eq. 43–45)."""
    w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha
    w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi**2 + 1)
    return P[..., 2] > -w2 * np.linalg.norm(P, axis=-1)


def ds_paper_unproject(mx: np.ndarray, my: np.ndarray, xi: float, alpha: float) -> np.ndarray:
    """Double sphere unprojection (eq. 46–51): normalized point → unit ray."""
    r2 = mx**2 + my**2
    mz = (1 - alpha**2 * r2) / (alpha * np.sqrt(1 - (2 * alpha - 1) * r2) + 1 - alpha)
    k = (mz * xi + np.sqrt(mz**2 + (1 - xi**2) * r2)) / (mz**2 + r2)
    return np.stack([k * mx, k * my, k * mz - xi], -1)


def eucm_paper(P: np.ndarray, alpha: float, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """EUCM projection of 3-D points (…, 3) to normalized (mx, my), Khomutenko et al. eq. 9–10."""
    x, y, z = P[..., 0], P[..., 1], P[..., 2]
    rho = np.sqrt(beta * (x**2 + y**2) + z**2)
    den = alpha * rho + (1 - alpha) * z
    return x / den, y / den


def eucm_paper_unproject(mx: np.ndarray, my: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """EUCM unprojection (Khomutenko et al. eq. 16–18): normalized point → unit ray."""
    r2 = mx**2 + my**2
    mz = (1 - beta * alpha**2 * r2) / (alpha * np.sqrt(1 - (2 * alpha - 1) * beta * r2) + 1 - alpha)
    ray = np.stack([mx, my, mz], -1)
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def reference_pixels(P: np.ndarray, calib: Calibration) -> np.ndarray:
    """3-D camera-frame points (N, 3) → raw pixels (N, 2), by OpenCV or the papers' equations."""
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    if calib.model in ("radtan", "rational"):
        return cv2.projectPoints(P, np.zeros(3), np.zeros(3), calib.K, calib.D)[0].reshape(-1, 2)
    if calib.model == "kb4":
        return cv2.fisheye.projectPoints(P[:, None], np.zeros(3), np.zeros(3), calib.K, calib.D)[0].reshape(-1, 2)
    mx, my = ds_paper(P, calib.xi, calib.alpha) if calib.model == "ds" else eucm_paper(P, calib.alpha, calib.beta)
    return np.stack([calib.fx * mx + calib.cx, calib.fy * my + calib.cy], -1)


def plane_points(n: int, half: float, seed: int) -> np.ndarray:
    """n random undistorted normalized points in [−half, half]², as 3-D points at random depths."""
    rng = np.random.default_rng(seed)
    xy, z = rng.uniform(-half, half, (n, 2)), rng.uniform(0.5, 50.0, n)
    return np.column_stack([xy * z[:, None], z])


def rays_within(n: int, max_angle_deg: float, seed: int) -> np.ndarray:
    """n random unit rays up to max_angle_deg off-axis (uniform in angle and azimuth)."""
    rng = np.random.default_rng(seed)
    theta, phi = np.radians(rng.uniform(0, max_angle_deg, n)), rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_projection_matches_opencv_or_the_paper(name):
    calib = CAMERAS[name]
    P = plane_points(400, 1.0, seed=1)
    u, v = project(P, calib)
    np.testing.assert_allclose(np.column_stack([u, v]), reference_pixels(P, calib), atol=1e-7, rtol=0)


def test_rational_with_zero_high_terms_is_radtan():
    radtan = KITTI_2011_09_26["02"]
    rational = Calibration(*radtan.size, radtan.fx, radtan.fy, radtan.cx, radtan.cy, *radtan.coeffs, model="rational")
    P = plane_points(200, 0.8, seed=2)
    np.testing.assert_allclose(project(P, rational), project(P, radtan), atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_jacobian_matches_finite_differences(name):
    calib = CAMERAS[name]
    model = lens.get(calib.model)
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-0.9, 0.9, 300), rng.uniform(-0.9, 0.9, 300)
    x[:3], y[:3] = [0.0, 1e-12, 0.3], [0.0, 0.0, 0.0]  # on and next to the axis (0/0 in the fisheye scale)
    h = 1e-6
    fd = [(np.array(model.project(x + h * dx, y + h * dy, calib.coeffs)) -
           np.array(model.project(x - h * dx, y - h * dy, calib.coeffs))) / (2 * h) for dx, dy in ((1, 0), (0, 1))]
    dxx, dxy, dyx, dyy = model.jacobian(x, y, calib.coeffs)
    np.testing.assert_allclose(np.stack([dxx, dxy, dyx, dyy]), [fd[0][0], fd[1][0], fd[0][1], fd[1][1]],
                               atol=1e-7, rtol=0)


@pytest.mark.parametrize("name", sorted(n for n, c in CAMERAS.items() if hasattr(lens.get(c.model), "project_axis")))
def test_project_axis_matches_the_reference_projection(name):
    calib = CAMERAS[name]
    rng = np.random.default_rng(4)
    t, fixed, rows = rng.uniform(-0.9, 0.9, 400), rng.uniform(-0.9, 0.9, 400), rng.random(400) < 0.5
    m, slope = lens.get(calib.model).project_axis(t, fixed, rows, calib.coeffs)

    def along(tt):  # the distorted coordinate along t, from OpenCV's pixels
        x, y = np.where(rows, tt, fixed), np.where(rows, fixed, tt)
        px = reference_pixels(np.column_stack([x, y, np.ones_like(x)]), calib)
        return np.where(rows, (px[:, 0] - calib.cx) / calib.fx, (px[:, 1] - calib.cy) / calib.fy)

    h = 1e-6
    np.testing.assert_allclose(m, along(t), atol=1e-9, rtol=0)
    np.testing.assert_allclose(slope, (along(t + h) - along(t - h)) / (2 * h), atol=1e-6, rtol=0)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_unproject_rays_inverts_the_reference_projection(name):
    calib = CAMERAS[name]
    # Fisheye models see past 90°: their rays go to 100° off-axis, where the plane z = 1 no longer reaches.
    limit = 100.0 if calib.model in ("kb4", "ds", "eucm") else 40.0
    rays = rays_within(500, limit, seed=4)
    if calib.model == "kb4":
        # cv2.fisheye.projectPoints divides by z; project the angle form directly (θ past 90°).
        theta, phi = np.arccos(rays[:, 2]), np.arctan2(rays[:, 1], rays[:, 0])
        td = theta * (1 + sum(k * theta ** (2 * i + 2) for i, k in enumerate(calib.coeffs)))
        m = np.column_stack([td * np.cos(phi), td * np.sin(phi)])
    else:
        px = reference_pixels(rays, calib)
        m = np.column_stack([(px[:, 0] - calib.cx) / calib.fx, (px[:, 1] - calib.cy) / calib.fy])
    back = np.column_stack(lens.get(calib.model).unproject_rays(m[:, 0], m[:, 1], calib.coeffs))
    np.testing.assert_allclose(back, rays, atol=1e-9, rtol=0)
    np.testing.assert_allclose(np.column_stack(pixel_rays(m[:, 0] * calib.fx + calib.cx, m[:, 1] * calib.fy + calib.cy,
                                                          calib)), rays, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", ["ds", "eucm"])
def test_closed_form_unprojection_matches_the_paper(name):
    calib = CAMERAS[name]
    rng = np.random.default_rng(5)
    mx, my = rng.uniform(-1.2, 1.2, 400), rng.uniform(-1.2, 1.2, 400)
    mine = np.column_stack(lens.get(calib.model).unproject_rays(mx, my, calib.coeffs))
    paper = (ds_paper_unproject(mx, my, calib.xi, calib.alpha) if name == "ds"
             else eucm_paper_unproject(mx, my, calib.alpha, calib.beta))
    ok = np.isfinite(mine).all(1)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(mine[ok], paper[ok], atol=1e-12, rtol=0)


def peak_angle(rho: np.ndarray, theta: np.ndarray) -> float:
    """The first angle where a sampled ρ(θ) stops growing (or turns NaN); inf when it grows to the end."""
    grows = np.diff(rho) > 0
    return float(theta[np.argmin(grows)]) if not grows.all() else np.inf


@pytest.mark.parametrize("xi, alpha", [(-0.2, 0.59), (0.3, 0.7), (-0.4, 0.45), (0.1, 0.3), (-0.6, 0.8)])
def test_ds_domain_is_the_paper_domain_where_one_to_one(xi, alpha):
    # The paper's domain is z > −w2·d1; where ρ(θ) stops growing first (strongly negative ξ), that bounds it.
    w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha
    w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi**2 + 1)
    theta = np.linspace(0, np.pi, 200001)
    mx, _ = ds_paper(np.column_stack([np.sin(theta), 0 * theta, np.cos(theta)]), xi, alpha)
    expected = min(np.arccos(-w2), peak_angle(mx, theta))
    assert lens.get("ds").fold_angle((xi, alpha)) == pytest.approx(expected, abs=2e-5)
    radius = np.tan(expected) if expected < np.pi / 2 else np.inf
    assert lens.get("ds").fold_radius((xi, alpha)) == pytest.approx(radius, rel=1e-4)


@pytest.mark.parametrize("alpha, beta", [(0.59, 1.13), (0.7, 0.8), (0.4, 1.5), (0.9, 2.0)])
def test_eucm_domain_is_where_the_projection_is_one_to_one(alpha, beta):
    # Khomutenko et al.: for α > 1/2 the valid set is z > −w·ρ with w = (1 − α)/α; for α ≤ 1/2 all of z > −w·ρ,
    # w = α/(1 − α), where the denominator stays positive.
    w = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha
    theta = np.linspace(0, np.pi, 200001)
    valid = np.cos(theta) > -w * np.sqrt(beta * np.sin(theta) ** 2 + np.cos(theta) ** 2)
    paper = theta[np.argmin(valid)] if not valid.all() else np.inf
    assert lens.get("eucm").fold_angle((alpha, beta)) == pytest.approx(paper, abs=2e-5)


def test_kb4_fold_is_where_theta_d_peaks():
    # θ(1 − 0.5 θ²) peaks at θ = √(2/3): inside 90°, so the plane's valid radius is tan of it.
    assert lens.get("kb4").fold_radius((-0.5, 0.0, 0.0, 0.0)) == pytest.approx(np.tan(np.sqrt(2 / 3)), rel=1e-9)
    assert lens.get("kb4").fold_radius(TUMVI.coeffs) == np.inf


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_undistort_pixels_inverts_every_model(name):
    calib = CAMERAS[name]
    P = plane_points(300, 0.7, seed=6)
    x, y = undistort_pixels(*project(P, calib), calib)
    np.testing.assert_allclose(x, P[:, 0] / P[:, 2], atol=1e-9, rtol=0)
    np.testing.assert_allclose(y, P[:, 1] / P[:, 2], atol=1e-9, rtol=0)


def test_undistort_names_pixels_past_90_degrees():
    with pytest.raises(AppdgenError, match=r"cannot be inverted at 1 point.*\(-?0\.0, 0\.0\).*past 90°"):
        undistort_pixels(np.array([0.0, 256.0]), np.array([0.0, 256.0]), TUMVI)
    x, _ = undistort_pixels(np.array([0.0, 256.0]), np.array([0.0, 256.0]), TUMVI, on_failure="nan")
    assert np.isnan(x[0]) and np.isfinite(x[1])


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_maps_match_the_reference_projection(name):
    calib = CAMERAS[name]
    size = (calib.width // 4, calib.height // 4)
    new_K = np.array([[size[0] / 1.6, 0, size[0] / 2], [0, size[0] / 1.6, size[1] / 2], [0, 0, 1]])
    map_x, map_y = lens.get(calib.model).maps(calib.K, calib.coeffs, new_K, size)
    assert map_x.dtype == np.float32 and map_x.shape == (size[1], size[0])
    rng = np.random.default_rng(7)
    i, j = rng.integers(0, size[1], 300), rng.integers(0, size[0], 300)
    P = np.column_stack([(j - new_K[0, 2]) / new_K[0, 0], (i - new_K[1, 2]) / new_K[1, 1], np.ones(300)])
    expected = reference_pixels(P, calib)
    np.testing.assert_allclose(map_x[i, j], expected[:, 0], atol=1e-3, rtol=0)
    np.testing.assert_allclose(map_y[i, j], expected[:, 1], atol=1e-3, rtol=0)


def test_from_arrays_takes_opencv_vectors_per_model():
    K = RATIONAL_8.K
    assert Calibration.from_arrays(2880, 1860, K, RATIONAL_8.D[:8], model="rational") == RATIONAL_8
    assert Calibration.from_arrays(2880, 1860, K, RATIONAL_12.D, model="rational") == RATIONAL_12
    assert Calibration.from_arrays(2880, 1860, K, np.r_[RATIONAL_12.D, 0, 0], model="rational") == RATIONAL_12
    assert Calibration.from_arrays(512, 512, TUMVI.K, TUMVI.D, model="kb4") == TUMVI
    radtan = Calibration.from_arrays(2880, 1860, K, np.r_[RATIONAL_8.D[:5], np.zeros(3)])
    assert radtan.model == "radtan" and radtan.coeffs == tuple(RATIONAL_8.D[:5])
    with pytest.raises(AppdgenError, match="needs model='rational'"):
        Calibration.from_arrays(2880, 1860, K, RATIONAL_8.D[:8])
    with pytest.raises(AppdgenError, match="'tilted' is not supported: OpenCV's tilted"):
        Calibration.from_arrays(2880, 1860, K, np.r_[RATIONAL_12.D, 0.01, 0], model="rational")


@pytest.mark.parametrize("name", sorted(lens.UNSUPPORTED))
def test_unsupported_models_are_refused_with_a_reason(name):
    with pytest.raises(AppdgenError, match=rf"^lens model '{name}' is not supported: .+; supported: radtan, "
                                           r"rational, kb4, ds, eucm$"):
        Calibration(100, 100, 50.0, 50.0, 50.0, 50.0, model=name)


@pytest.mark.parametrize("model, coeffs, message", [("ds", {"xi": -0.2, "alpha": 1.5}, "double sphere needs"),
                                                    ("ds", {"xi": -1.5, "alpha": 0.5}, "double sphere needs"),
                                                    ("eucm", {"alpha": 0.5, "beta": 0.0}, "eucm needs")])
def test_out_of_domain_coefficients_are_refused(model, coeffs, message):
    with pytest.raises(AppdgenError, match=message):
        Calibration(100, 100, 50.0, 50.0, 50.0, 50.0, model=model, **coeffs)


def test_first_nonpositive_finds_the_crossing():
    assert numerics.first_nonpositive(lambda t: 1.0 - t, 4.0) == pytest.approx(1.0, abs=1e-15)
    assert numerics.first_nonpositive(lambda t: 1.0 + t, 4.0) == np.inf


def test_kb4_maps_match_opencv_fisheye_maps():
    new_K = np.array([[120.0, 0, 255.5], [0, 120.0, 255.5], [0, 0, 1]])
    mine = lens.get("kb4").maps(TUMVI.K, TUMVI.coeffs, new_K, (512, 512))
    cv = cv2.fisheye.initUndistortRectifyMap(TUMVI.K, TUMVI.D, np.eye(3), new_K, (512, 512), cv2.CV_32FC1)
    assert np.abs(mine[0] - cv[0]).max() < 1e-3 and np.abs(mine[1] - cv[1]).max() < 1e-3
