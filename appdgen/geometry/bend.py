"""The label, decomposed: the warp from the reference rectification to a sample's, split into its best-fit affine
part (a shift and a zoom that one image shows only through scene priors) and the non-affine rest (bent lines).

A sample image is the reference rectification warped by W(p) = K̂*·undistort(M̂m(p); Θ*): for each output pixel
p of the sample, the reference output pixel showing the same ray. W is fitted by least squares with an affine map
A·p + t; the rest r(p) = W(p) − (A·p + t) is what bends straight lines. Lengths are brought to raw pixels through
the reference map's own Jacobian J*(p) = ∂M̂*/∂p (‖J*·r‖ ≈ how far the raw sample position moves), so that
`bend_px` compares with APPD: both are means over the output image, in raw pixels.

Everything is evaluated on a fixed grid of fractional output positions (GRID_COLUMNS across), in output pixels of
a raw-size output (isotropic for raw-aspect crops): the split depends on the two calibrations and their crops
only, never on the build's output size, and costs well under a millisecond for the pinhole models.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.geometry.crop import Crop
from appdgen.geometry.distortion import distort_normalized, distortion_jacobian, undistort_pixels

#: Grid points across the output image (rows in the raw aspect): the warp is smooth, ~3,400 points at KITTI's
#: aspect hold the split to ~1e-3 of the full-grid value for radtan, ~1e-2 for fisheye lenses (tests/test_bend.py).
GRID_COLUMNS = 96


@dataclass(frozen=True)
class WarpSplit:
    """A sample's warp split into affine part and rest (raw pixels; `scale` unitless).

    bend_px: mean over the output image of the non-affine rest's length; shift_x_px, shift_y_px: the affine part's
    displacement at the image centre (sample minus reference position, raw pixels); scale: √det A, the affine
    part's zoom (> 1: the sample's image spans more of the reference's, i.e. it shows a wider view);
    appd_grid_px: APPD on the same grid (the full-grid label to ~1e-3), the yardstick for bend_px.
    """

    bend_px: float
    shift_x_px: float
    shift_y_px: float
    scale: float
    appd_grid_px: float


#: The split of a rectification against itself, exactly (a reference sample's: not the fit's rounding noise).
NO_WARP = WarpSplit(bend_px=0.0, shift_x_px=0.0, shift_y_px=0.0, scale=1.0, appd_grid_px=0.0)


def grid(calib: Calibration, columns: int = GRID_COLUMNS) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (u, v) of a columns × rows grid over a raw-size output image, in output pixels."""
    width, height = calib.size
    rows = max(4, round(columns * height / width))
    u = (np.arange(columns) + 0.5) * width / columns - 0.5
    v = (np.arange(rows) + 0.5) * height / rows - 0.5
    uu, vv = np.meshgrid(u, v)
    return uu.ravel(), vv.ravel()


def _normalized(crop: Crop, calib: Calibration, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw-size output pixels → undistorted normalized coordinates of the crop (K̂⁻¹)."""
    k = crop.camera_matrix(calib.size)
    return (u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1]


def _raw(calib: Calibration, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates → raw pixels (the map M̂ at those points)."""
    xd, yd = distort_normalized(x, y, calib)
    return calib.fx * xd + calib.cx, calib.fy * yd + calib.cy


class AffineRest(NamedTuple):
    """A field's least-squares affine fit and what it leaves: the rest at each point (pixels) and the fit's
    coefficients (t, a_u, a_v: value = t + a_u·u + a_v·v, pixels and pixels per pixel) for u and for v."""

    rest_u: np.ndarray
    rest_v: np.ndarray
    coef_u: np.ndarray
    coef_v: np.ndarray


def affine_rest(u: np.ndarray, v: np.ndarray, du: np.ndarray, dv: np.ndarray, design: np.ndarray | None = None
                ) -> AffineRest:
    """The part of a field (du, dv) at points (u, v) that no affine map of (u, v) explains, by least squares
    (pixels); positions or displacements give the same rest. `design`: the fit's N×3 matrix [1, u, v], when cached."""
    design = np.column_stack([np.ones_like(u), u, v]) if design is None else design
    coef_u, coef_v = (np.linalg.lstsq(design, w, rcond=None)[0] for w in (du, dv))
    return AffineRest(du - design @ coef_u, dv - design @ coef_v, coef_u, coef_v)


@dataclass(frozen=True)
class WarpField:
    """The warp's displacement on grid(reference, columns), per point (N×2, raw pixels, x then y): `moved`, how far
    the sample's raw sample position is from the reference's (M̂m(p) − M̂*(p): APPD is its mean length); `rest`, the
    non-affine part through J* (bend_px is its mean length). Row-major over the grid's rows × columns."""

    moved: np.ndarray
    rest: np.ndarray
    columns: int
    rows: int

    @property
    def bend_px(self) -> float:
        """Mean length of the non-affine rest (raw px): WarpSplit.bend_px."""
        return float(np.hypot(*self.rest.T).mean())

    @property
    def appd_px(self) -> float:
        """Mean length of the displacement on the grid (raw px): WarpSplit.appd_grid_px."""
        return float(np.hypot(*self.moved.T).mean())


@dataclass(frozen=True)
class _ReferenceGrid:
    """What a split needs of the reference alone (computed once per reference, crop and grid): the grid (u, v),
    the affine fit's design matrix, K̂* and M̂* at the grid (raw px)."""

    u: np.ndarray
    v: np.ndarray
    design: np.ndarray
    k: np.ndarray
    raw_u: np.ndarray
    raw_v: np.ndarray


@functools.lru_cache(maxsize=8)
def _reference_grid(reference: Calibration, reference_crop: Crop, columns: int) -> _ReferenceGrid:
    """_ReferenceGrid of a reference rectification (cached: a build splits every sample against one reference)."""
    u, v = grid(reference, columns)
    raw_u, raw_v = _raw(reference, *_normalized(reference_crop, reference, u, v))
    for a in (u, v, raw_u, raw_v):
        a.flags.writeable = False  # shared by every split of this reference
    design = np.column_stack([np.ones_like(u), u, v])
    design.flags.writeable = False
    return _ReferenceGrid(u, v, design, reference_crop.camera_matrix(reference.size), raw_u, raw_v)


def _warp(reference: Calibration, k: np.ndarray, sample: Calibration, sample_crop: Crop, u: np.ndarray,
          v: np.ndarray) -> tuple[np.ndarray, ...]:
    """At sample output pixels (u, v): M̂m(p) (raw px), the reference's undistorted normalized (x, y) of it, and
    W(p) = K̂*·(x, y) (reference output px; k = K̂*)."""
    raw_u, raw_v = _raw(sample, *_normalized(sample_crop, sample, u, v))  # M̂m(p)
    x, y = undistort_pixels(raw_u, raw_v, reference)
    return raw_u, raw_v, x, y, k[0, 0] * x + k[0, 2], k[1, 1] * y + k[1, 2]


def output_warp(reference: Calibration, reference_crop: Crop, sample: Calibration, sample_crop: Crop,
                u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W(p) at sample output pixels (u, v) of a raw-size output: the reference output pixel showing the same ray
    (reference output px)."""
    if reference.size != sample.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {sample.size}")
    k = reference_crop.camera_matrix(reference.size)
    wu, wv = _warp(reference, k, sample, sample_crop, np.asarray(u, np.float64), np.asarray(v, np.float64))[4:]
    return wu, wv


def output_rest(reference: Calibration, reference_crop: Crop, sample: Calibration, sample_crop: Crop,
                u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The non-affine rest of W at sample output pixels (u, v), in sample output pixels (N×2): A⁻¹·r(p), with
    W(p) = A·p + t + r(p) fitted by least squares over the given points. Edge points p_i of a line straight in
    the reference rectification have p_i + rest(p_i) collinear: what the sample image shows of the bend."""
    u, v = np.asarray(u, np.float64).ravel(), np.asarray(v, np.float64).ravel()
    fit = affine_rest(u, v, *output_warp(reference, reference_crop, sample, sample_crop, u, v))
    rest, coef_u, coef_v = np.column_stack([fit.rest_u, fit.rest_v]), fit.coef_u, fit.coef_v
    a = np.array([[coef_u[1], coef_u[2]], [coef_v[1], coef_v[2]]])
    return np.linalg.solve(a, rest.T).T


def _split(reference: Calibration, reference_crop: Crop, sample: Calibration, sample_crop: Crop, columns: int
           ) -> tuple[WarpField, np.ndarray, np.ndarray]:
    """The field on the grid and the affine fit's coefficients (u and v: t, a_u, a_v in reference output pixels)."""
    if reference.size != sample.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {sample.size}")
    ref = _reference_grid(reference, reference_crop, columns)
    u, v, design, k = ref.u, ref.v, ref.design, ref.k
    raw_u, raw_v, x, y, wu, wv = _warp(reference, k, sample, sample_crop, u, v)
    ru, rv, coef_u, coef_v = affine_rest(u, v, wu, wv, design)
    # J*(W(p)) = diag(fx, fy)·∂distort/∂(x, y)·K̂*⁻¹: raw pixels per reference output pixel where the ray lands.
    j11, j12, j21, j22 = distortion_jacobian(x, y, reference)
    sx, sy = reference.fx / k[0, 0], reference.fy / k[1, 1]
    rest = np.column_stack([sx * (j11 * ru + j12 * rv), sy * (j21 * ru + j22 * rv)])
    moved = np.column_stack([raw_u - ref.raw_u, raw_v - ref.raw_v])  # M̂m(p) − M̂*(p)
    return WarpField(moved, rest, columns, len(u) // columns), coef_u, coef_v


def warp_field(reference: Calibration, reference_crop: Crop, sample: Calibration, sample_crop: Crop,
               columns: int = GRID_COLUMNS) -> WarpField:
    """The warp's displacement and its non-affine rest at each point of a columns-wide grid (raw pixels); zeros,
    exactly, for the reference rectification itself."""
    field = _split(reference, reference_crop, sample, sample_crop, columns)[0]
    if sample == reference and sample_crop == reference_crop:
        return WarpField(np.zeros_like(field.moved), np.zeros_like(field.rest), field.columns, field.rows)
    return field


def split_warp(reference: Calibration, reference_crop: Crop, sample: Calibration, sample_crop: Crop,
               columns: int = GRID_COLUMNS) -> WarpSplit:
    """The affine/non-affine split of the warp from the reference rectification to the sample's (raw pixels);
    NO_WARP, exactly, for the reference rectification itself."""
    if sample == reference and sample_crop == reference_crop:
        return NO_WARP
    field, coef_u, coef_v = _split(reference, reference_crop, sample, sample_crop, columns)
    return WarpSplit(
        bend_px=field.bend_px,
        **_centre_shift(reference, reference_crop, coef_u, coef_v),
        scale=float(np.sqrt(abs(coef_u[1] * coef_v[2] - coef_u[2] * coef_v[1]))),
        appd_grid_px=field.appd_px,
    )


def _centre_shift(reference: Calibration, crop: Crop, coef_u: np.ndarray, coef_v: np.ndarray) -> dict[str, float]:
    """The affine part's displacement at the output centre, through M̂* (raw pixels: shift_x_px, shift_y_px)."""
    width, height = reference.size
    cu, cv = np.array([(width - 1) / 2]), np.array([(height - 1) / 2])
    au = coef_u[0] + coef_u[1] * cu + coef_u[2] * cv
    av = coef_v[0] + coef_v[1] * cu + coef_v[2] * cv
    moved_u, moved_v = _raw(reference, *_normalized(crop, reference, au, av))
    still_u, still_v = _raw(reference, *_normalized(crop, reference, cu, cv))
    return {"shift_x_px": float(moved_u[0] - still_u[0]), "shift_y_px": float(moved_v[0] - still_v[0])}
