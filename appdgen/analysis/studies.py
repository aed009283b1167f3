"""The paper's analyses as pure functions: per-parameter APPD sweeps, APPD against reprojection error, day-to-day drift.

Conventions. Θ* is the reference calibration and Θm another one (perturbed, sampled, or another day's). Output
positions are pixels of the rectified image at one output size, whose camera matrix is K̂(Θ) (from Θ's own valid
crop); raw positions are pixels of the raw image. APPD is in raw pixels or in % of the raw diagonal √(W²+H²).
Parameters are the calibration's own (``calib.param_names``: fx, fy, cx, cy and its lens model's coefficients).
``max_fov`` (degrees, horizontal; None: unbounded) bounds the rectified field of view of Θ* and every Θm alike.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from appdgen.calib.calibration import DISTORTION, Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd_px, px_to_pct
from appdgen.geometry.crop import Crop, valid_region
from appdgen.geometry.distortion import distort_to_pixels, undistort_pixels
from appdgen.geometry.maps import Rectification, rectify
from appdgen.sampling.ranges import PAPER_RANGES

#: The two reprojection scenarios of the paper's figure: (a) synthetic and (b) physical.
SCENARIOS: tuple[str, ...] = ("synthetic", "physical")

Points = tuple[np.ndarray, np.ndarray]
#: One sampled calibration: its fractions t (param_names order), Θm = Θ* × (1 + t), and Θm's valid crop.
Draw = tuple[np.ndarray, Calibration, Crop]


# --- sweep: APPD as one parameter changes -----------------------------------------------------------------------


def sweep_fractions(start: float, stop: float, steps: int) -> np.ndarray:
    """`steps` fractions t from start to stop inclusive (unitless), float noise around 0 snapped to exactly 0."""
    if steps < 2:
        raise AppdgenError(f"a sweep needs at least 2 t values, got {steps}")
    t = np.linspace(start, stop, steps)
    t[np.abs(t) <= 1e-12 * max(abs(start), abs(stop))] = 0.0
    return t


def sweep(calib: Calibration, params: Sequence[str], fractions: np.ndarray,
          size: tuple[int, int] | None = None, max_fov: float | None = None) -> dict[str, np.ndarray]:
    """APPD (% of the raw diagonal) for each non-zero parameter alone × (1 + t), per t; NaN where that is invalid."""
    unknown = [name for name in params if name not in calib.param_names]
    if unknown:
        raise AppdgenError(f"unknown parameter(s) {', '.join(unknown)} for lens model {calib.model}; expected some "
                           f"of {', '.join(calib.param_names)}")
    # Parameters that are 0 are left out: multiplying them changes nothing, the curve would be flat zero.
    reference = rectify(calib, size, max_fov=max_fov)
    return {name: np.array([_perturbed_pct(reference, name, t, max_fov) for t in fractions])
            for name in params if getattr(calib, name) != 0.0}


def _perturbed_pct(reference: Rectification, name: str, t: float, max_fov: float | None) -> float:
    """APPD (% of the raw diagonal) of the reference with one parameter × (1 + t); NaN if that is invalid."""
    try:
        other = rectify(reference.calib.perturb(**{name: t}), reference.size, max_fov=max_fov)
    except AppdgenError:  # fold-over, no valid region, or a focal length pushed to ≤ 0
        return float("nan")
    return px_to_pct(appd_px(reference, other), reference.calib)


# --- reprojection error against APPD ------------------------------------------------------------------------------


def to_output(new_k: np.ndarray, x: np.ndarray, y: np.ndarray) -> Points:
    """Undistorted normalized (x, y) → output pixel position K̂·(x, y, 1)."""
    return new_k[0, 0] * x + new_k[0, 2], new_k[1, 1] * y + new_k[1, 2]


def rectify_points(rect: Rectification, u: np.ndarray, v: np.ndarray) -> Points:
    """Raw pixel (u, v) → output pixel: undistort with rect's Θ, then K̂(Θ); NaN where undistortion fails."""
    return to_output(rect.new_camera_matrix, *undistort_pixels(u, v, rect.calib, on_failure="nan"))


def sample_rays(rect: Rectification, count: int, rng: np.random.Generator) -> Points:
    """Normalized (x, y) = (X/Z, Y/Z) of 3-D points seen uniformly over rect's output frame, i.e. its crop R."""
    crop = rect.crop
    return rng.uniform(crop.x0, crop.x1, count), rng.uniform(crop.y0, crop.y1, count)


def synthetic_error(reference: Rectification, other: Rectification, x: np.ndarray, y: np.ndarray) -> float:
    """Mean ‖K̂*·x − rectify_m(project_*(x))‖ (output px): Θ*'s raw image rectified with Θ* and with Θm."""
    u, v = distort_to_pixels(x, y, reference.calib)
    # rectify_*(project_*(x)) is K̂*·x exactly: the ideal positions need no undistortion.
    return _mean_distance(to_output(reference.new_camera_matrix, x, y), rectify_points(other, u, v))


def physical_error(reference: Rectification, other: Rectification, x: np.ndarray, y: np.ndarray) -> float:
    """Mean ‖K̂*·x − rectify_*(project_m(x))‖ (output px) over the points Θm projects inside the raw frame."""
    u, v = distort_to_pixels(x, y, other.calib)
    calib = other.calib
    seen = (u >= 0) & (u <= calib.width - 1) & (v >= 0) & (v <= calib.height - 1)  # the drifted sensor's view
    return _mean_distance(to_output(reference.new_camera_matrix, x[seen], y[seen]),
                          rectify_points(reference, u[seen], v[seen]))


def _mean_distance(a: Points, b: Points) -> float:
    """Mean distance between paired positions (their unit), skipping NaN ones (failed undistortion); NaN if none."""
    distance = np.hypot(a[0] - b[0], a[1] - b[1])
    distance = distance[np.isfinite(distance)]
    return float(distance.mean()) if distance.size else float("nan")


_ERRORS = {"synthetic": synthetic_error, "physical": physical_error}


def study_ranges(calib: Calibration) -> dict[str, tuple[float, float]]:
    """The paper's ranges (fractions) for calib's parameters; a coefficient radtan lacks gets the distortion range."""
    distortion = PAPER_RANGES[DISTORTION[0]]  # the paper perturbs every distortion coefficient alike: ±15 %
    return {name: PAPER_RANGES.get(name, distortion) for name in calib.param_names}


def sample_calibrations(calib: Calibration, count: int, rng: np.random.Generator,
                        ranges: Mapping[str, tuple[float, float]] | None = None,
                        max_fov: float | None = None) -> tuple[list[Draw], int]:
    """`count` valid draws, t uniform in `ranges` (fractions; default study_ranges), and the invalid ones skipped."""
    ranges = study_ranges(calib) if ranges is None else ranges
    names = calib.param_names
    lo, hi = np.array([ranges.get(name, (0.0, 0.0)) for name in names]).T  # parameters not in ranges stay fixed
    draws: list[Draw] = []
    skipped = 0
    while len(draws) < count:
        t = rng.uniform(lo, hi)
        try:
            other = calib.perturb(**dict(zip(names, t.tolist(), strict=True)))
            draws.append((t, other, valid_region(other, max_fov=max_fov)))
        except AppdgenError:  # fold-over or no valid region: not a usable calibration, draw again
            skipped += 1
            if skipped > 10 * count + 100:
                raise AppdgenError(f"{skipped} of {skipped + len(draws)} sampled calibrations are invalid: "
                                   "ranges too wide for this lens") from None
    return draws, skipped


@dataclass(frozen=True)
class ReprojectionStudy:
    """Per sampled Θm: t (`params` order), APPD (raw px, %), reprojection error per scenario (output px)."""

    fractions: np.ndarray
    appd_px: np.ndarray
    appd_pct: np.ndarray
    reproj_px: dict[str, np.ndarray]
    skipped: int
    points: int
    size: tuple[int, int]
    params: tuple[str, ...]


def reprojection_study(calib: Calibration, samples: int, scenarios: Sequence[str] = SCENARIOS, seed: int = 0,
                       size: tuple[int, int] | None = None, points: int = 1000,
                       ranges: Mapping[str, tuple[float, float]] | None = None,
                       max_fov: float | None = None) -> ReprojectionStudy:
    """APPD and reprojection error (output px at `size`) for `samples` valid Θm drawn around Θ* in `ranges`."""
    unknown = sorted(set(scenarios) - set(_ERRORS))
    if unknown:
        raise AppdgenError(f"unknown scenario(s) {', '.join(unknown)}; expected {' or '.join(SCENARIOS)}")
    if samples < 1 or points < 1:
        raise AppdgenError(f"need at least 1 sample and 1 point, got samples={samples} points={points}")
    rng = np.random.default_rng(seed)
    reference = rectify(calib, size, max_fov=max_fov)
    x, y = sample_rays(reference, points, rng)
    draws, skipped = sample_calibrations(calib, samples, rng, ranges, max_fov)
    appd = np.empty(samples)
    errors = {name: np.empty(samples) for name in scenarios}
    for i, (_, other, crop) in enumerate(draws):
        rect = rectify(other, reference.size, crop)
        appd[i] = appd_px(reference, rect)
        for name in scenarios:
            errors[name][i] = _ERRORS[name](reference, rect, x, y)
    fractions = np.array([t for t, _, _ in draws])
    return ReprojectionStudy(fractions, appd, appd * 100.0 / calib.diagonal, errors, skipped, points, reference.size,
                             calib.param_names)


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of paired samples (unitless; pairs with a NaN dropped, ties get mean ranks)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    ra, rb = _ranks(a[keep]), _ranks(b[keep])
    if len(ra) < 2 or ra.std() == 0 or rb.std() == 0:
        return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])


def _ranks(values: np.ndarray) -> np.ndarray:
    """Ranks 0…n−1 of the values, tied values sharing their mean rank."""
    order = np.argsort(values, kind="stable")
    ranks = np.empty(len(values))
    ranks[order] = np.arange(len(values))
    _, group, counts = np.unique(values, return_inverse=True, return_counts=True)
    return (np.bincount(group, weights=ranks) / counts)[group]


# --- drift: APPD between calibrations of one camera -----------------------------------------------------------------


def drift_matrix(calibs: Sequence[Calibration], size: tuple[int, int] | None = None,
                 labels: Sequence[str] | None = None, max_fov: float | None = None) -> np.ndarray:
    """Symmetric matrix of APPD (raw px) between every pair of calibrations of one raw size (any lens models)."""
    if len({c.size for c in calibs}) > 1:
        names = labels or [str(i) for i in range(len(calibs))]
        listed = ", ".join(f"{name} {c.width}x{c.height}" for name, c in zip(names, calibs, strict=True))
        raise AppdgenError(f"calibrations differ in raw size: {listed}")
    rects = [rectify(c, size, max_fov=max_fov) for c in calibs]
    matrix = np.zeros((len(rects), len(rects)))
    for i in range(len(rects)):
        for j in range(i + 1, len(rects)):
            matrix[i, j] = matrix[j, i] = appd_px(rects[i], rects[j])  # mirrored: symmetric by construction
    return matrix


def round_significant(calib: Calibration, digits: int) -> Calibration:
    """Θ with every parameter rounded to `digits` significant digits (as in the reduced KITTI files)."""
    return calib.replace(**{name: float(f"{value:.{digits}g}") for name, value in calib.params().items()})
