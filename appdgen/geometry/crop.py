"""The valid region R: the largest raw-aspect rectangle of the undistorted normalized plane holding only valid points.

A normalized point (x, y) is valid when its distorted pixel position lies in [0, W−1] × [0, H−1]. Where the
distortion is monotone (the guard makes sure), u grows with x and v with y, so the valid set is bounded by four graphs:

    L(y) ≤ x ≤ R(y)   (u = 0 and u = W−1),        T(x) ≤ y ≤ B(x)   (v = 0 and v = H−1),

and a rectangle [x0, x1] × [y0, y1] is valid exactly when x0 ≥ max L, x1 ≤ min R over [y0, y1] and y0 ≥ max T,
y1 ≤ min B over [x0, x1]. The four graphs are solved by Newton's method on dense uniform grids (1,025 nodes); a
max/min over an interval is taken over the nodes inside plus the linearly interpolated ends. That misses a peak
between two nodes by f''·δ²/2 (δ: its distance to the nearest node, ≤ Δ/2), so on nested grids (257, 1,025 …)
a peak near one node errs the same at every resolution. The rectangle grown on the nodes is then assessed with a
parabola through the nodes at each side's peak and ends: where that predicts the crop is off by more than
GRID_ERROR_PX output px (at the raw size), or pokes out of the frame by more than GRID_EXCESS_PX raw px, it is
grown again against the curves themselves, solved exactly at the interval ends and at each parabola peak (steep
rational and EUCM lenses). Grids coarser than the default (the sampler's 257-node search) skip that pass: they are
estimates, erring by up to ~2e-2 output px on KITTI (and 1.3e-3 raw px on the steep rational lens). KITTI-range
radtan crops (measured: ≤ 1.15e-3 output px and ≤ 1.6e-4 raw px off over 1,200 draws of the paper's ranges) stay
on the nodes, bit for bit as before. The size is the root of "spare = 0" (the slack left around a rectangle of
that size) and, when one axis has slack, the rectangle is centred in the range of feasible positions along it.
search_region is the samplers' quick estimate: the same nodes' crop over a box given around R's slide box
(slide_box: where the four curves bind around R) instead of the frame box.

Public functions come first; the boundary graphs (_Boundaries: left, right, top, bottom) and the rectangle grown
between them follow.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.distortion import (
    distort_to_pixels,
    distortion_jacobian,
    pixel_rays,
    radial_fold_radius,
    undistort_pixels,
)

GRID_NODES = 1025
#: Predicted error of the nodes' crop (output px at the raw size, either way) above which it is grown again against
#: the exact boundary curves: above the 1.15e-3 px KITTI-range radtan crops reach, whose values must not change.
GRID_ERROR_PX = 2e-3
#: Predicted excess of the nodes' crop past the frame (raw px) above which the same: half the guard's 1e-3 px.
GRID_EXCESS_PX = 5e-4
#: Newton steps for the boundary curves: ~6 suffice near the axis, a fisheye's far rows take up to ~30.
NEWTON_STEPS = 16
_TOL = 1e-11  # normalized units: about 1e-8 output pixel


@dataclass(frozen=True)
class Crop:
    """The valid region R as [x0, x1] × [y0, y1] in undistorted normalized coordinates."""

    x0: float
    y0: float
    x1: float
    y1: float

    @classmethod
    def around(cls, xc: float, yc: float, s: float, aspect: float) -> "Crop":
        """The rectangle of height s and width aspect·s centred on (xc, yc), normalized."""
        return cls(xc - 0.5 * aspect * s, yc - 0.5 * s, xc + 0.5 * aspect * s, yc + 0.5 * s)

    def camera_matrix(self, size: tuple[int, int]) -> np.ndarray:
        """K̂ (pixels) mapping R onto the output area [−0.5, w−0.5] × [−0.5, h−0.5]."""
        w, h = size
        fx = w / (self.x1 - self.x0)
        fy = h / (self.y1 - self.y0)
        return np.array([[fx, 0.0, -0.5 - fx * self.x0], [0.0, fy, -0.5 - fy * self.y0], [0.0, 0.0, 1.0]])


def valid_region(calib: Calibration, nodes: int = GRID_NODES, guard: bool = True,
                 max_fov: float | None = None) -> Crop:
    """The largest valid rectangle of raw aspect W:H (in pixels), centred where it can slide; normalized units.

    `nodes` sets the boundary grids' resolution (coarser than GRID_NODES: a quick estimate without the exactness
    pass, 257 nodes err by up to ~2e-2 output px; finer: tighter bounds, by (1024/(nodes − 1))²); `guard=False`
    skips the final guard (monotone lens over R, R inside the frame), for searches that guard their final answer.
    `max_fov` (degrees, None = unbounded) keeps R within that horizontal field of view: inside the raw-aspect box
    |x| ≤ tan(max_fov/2) around the principal point (see fov_box).
    """
    r_fold = radial_fold_radius(calib)
    bounds = _boundaries(calib, r_fold, nodes, _bounded_box(calib, r_fold, max_fov))
    aspect = _aspect(calib)
    s, xc, yc = _largest(bounds, aspect, calib)
    # Coarser grids than the default are the sampler's quick estimates: they skip the exactness pass.
    fine = ((GRID_NODES - 1) / (nodes - 1)) ** 2  # the grid error scales with the node step squared
    if fine <= 1.0 and _off_by_more(_grid_error(bounds, aspect, s, xc, yc, calib), fine):
        # Strongly curved boundaries: the nodes miss a peak between them by up to f''Δ²/8, so the rectangle is
        # grown again against the curves themselves (solved at the interval ends and at each peak).
        for graph in bounds:
            graph.exact = True
        xc, yc, spare = _centre(s, aspect, bounds, xc, yc)
        hi, spare_hi = np.inf, -np.inf
        while spare < 0:  # the nodes' rectangle pokes out: shrink by twice its excess until it fits
            hi, spare_hi = s, spare
            s = s + 2.0 * spare if np.isfinite(spare) else 0.5 * s
            xc, yc, spare = _centre(s, aspect, bounds, xc, yc)
        s, xc, yc = _grow(bounds, aspect, s, xc, yc, spare, hi, spare_hi)
    crop = Crop.around(xc, yc, s, aspect)
    if guard:
        _check_crop(calib, crop, r_fold)
    return crop


def search_region(calib: Calibration, box: tuple[float, float, float, float], nodes: int,
                  max_fov: float | None = None) -> Crop | None:
    """A quick estimate of R (normalized) for searches: boundary grids of `nodes` nodes over a given box (x0, x1,
    y0, y1) instead of the calibration's frame box, no exactness pass and no guard; None where the box may cut R
    (use valid_region then).

    The box need only hold R's slide box (a sampler's box predicted around it, see slide_box): the curves
    matter there alone, so no frame box is solved per call (its border undistortion was ~40 % of a 257-node
    valid_region). `max_fov` cuts it as valid_region's. Like valid_region's coarse grids, this errs by the
    grid's f''Δ²/8.
    """
    cut = _fov_cut(calib, box, max_fov)
    crop, bounds = _nodes_region(calib, nodes, cut)
    # The slide box within 1 % of a side the given box set (not max_fov): the box may have cut it, and R with it.
    margin = (0.01 * (box[1] - box[0]),) * 2 + (0.01 * (box[3] - box[2]),) * 2
    if any(cut[i] == box[i] and abs(side - box[i]) < margin[i] for i, side in enumerate(_slide_box_of(bounds, crop))):
        return None
    return crop


def slide_box(calib: Calibration, nodes: int, max_fov: float | None = None) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1), normalized: the slide box, where the boundary curves bind around R (R's own extent along
    an axis it fills), from the boundary curves on `nodes` nodes over the calibration's own box."""
    crop, bounds = _nodes_region(calib, nodes, _bounded_box(calib, radial_fold_radius(calib), max_fov))
    return _slide_box_of(bounds, crop)


def fov_box(calib: Calibration, max_fov: float) -> tuple[float, float]:
    """Half-width tan(max_fov/2) and half-height (the same over the raw aspect) of the max_fov box, normalized."""
    # Bounding x alone left a fisheye's vertical extent lopsided (tan grows fast towards 90°): the T265's rectangle,
    # centred in it, looked 60° down. The raw-aspect box around the principal point keeps the view ahead.
    check_max_fov(max_fov)
    half = float(np.tan(np.radians(max_fov) / 2.0))
    return half, half / _aspect(calib)


def check_max_fov(max_fov: float | None) -> None:
    """Refuse a --max-fov (degrees) that is not a number in (0, 180); None (unbounded) passes."""
    if max_fov is None:
        return
    if not (isinstance(max_fov, (int, float)) and 0.0 < max_fov < 180.0):
        raise AppdgenError(f"--max-fov {max_fov!r}: must be a horizontal field of view between 0 and 180 degrees "
                           "(exclusive)")


def check_output_size(calib: Calibration, size: tuple[int, int]) -> tuple[int, int]:
    """Validate an output size (pixels): positive and within a pixel of the raw aspect ratio."""
    w, h = size
    if w < 1 or h < 1:
        raise AppdgenError(f"output size {w}x{h} must be positive")
    if abs(w - h * calib.width / calib.height) > 1.0 and abs(h - w * calib.height / calib.width) > 1.0:
        raise AppdgenError(
            f"output size {w}x{h} is more than a pixel off the raw aspect {calib.width}:{calib.height}"
        )
    return int(w), int(h)


# --- the boundary graphs and the rectangle grown between them ------------------------------------------------


class _Graph:
    """A boundary curve sampled on a uniform grid, with interval extrema from the nodes or, once `exact` is set,
    from the curve itself (`solve`: exact values at any points); scale·|slope|: raw pixels per normalized unit
    across the frame edge at each node (scale: fx or fy, slope: ∂m/∂t)."""

    def __init__(self, t: np.ndarray, f: np.ndarray, solve: Callable[[np.ndarray], np.ndarray], slope: np.ndarray,
                 scale: float):
        self.t, self.f, self.solve, self.slope, self.scale = t, f, solve, slope, scale
        self.t0, self.dt = float(t[0]), float(t[1] - t[0])
        self.exact = False

    def _span(self, a: float, b: float) -> tuple[int, int]:
        """Index range of the nodes strictly inside [a, b]."""
        i0 = max(math.floor((a - self.t0) / self.dt) + 1, 0)
        return i0, min(math.ceil((b - self.t0) / self.dt), len(self.t))

    def _values(self, a: float, b: float) -> np.ndarray:
        """Values at the nodes strictly inside [a, b] and (interpolated) at a and b."""
        i0, i1 = self._span(a, b)
        ends = np.interp([a, b], self.t, self.f, left=np.nan, right=np.nan)
        return np.concatenate([self.f[i0:i1], ends])

    def max_on(self, a: float, b: float) -> float:
        """max f over [a, b]; +inf where the curve is undefined there."""
        if self.exact:
            return self._exact_max(a, b, 1.0)
        v = self._values(a, b)
        return float(np.inf) if np.isnan(v).any() else float(v.max())

    def min_on(self, a: float, b: float) -> float:
        """min f over [a, b]; −inf where the curve is undefined there."""
        if self.exact:
            return -self._exact_max(a, b, -1.0)
        v = self._values(a, b)
        return float(-np.inf) if np.isnan(v).any() else float(v.min())

    def _exact_max(self, a: float, b: float, sign: float) -> float:
        """max of sign·f over [a, b] from the curve: solved at a and b and at each candidate peak between nodes."""
        if not self.t[0] <= a <= b <= self.t[-1]:
            return float(np.inf)
        i0, i1 = self._span(a, b)
        t = np.concatenate([[a], self.t[i0:i1], [b]])
        f = np.concatenate([[0.0], sign * self.f[i0:i1], [0.0]])
        f[[0, -1]] = sign * self.solve(np.array([a, b]))
        peaks = _parabola_peaks(t, f)
        return float(max(f.max(), (sign * self.solve(peaks)).max())) if peaks.size else float(f.max())

    def curve_max(self, a: float, b: float, sign: float) -> tuple[float, float]:
        """(max of sign·f over [a, b], raw px per unit across the edge there), the max estimated between the nodes
        from parabolas through them (normalized units)."""
        i0, i1 = self._span(a, b)
        if i1 - i0 < 3 or not self.t[0] <= a <= b <= self.t[-1]:
            return sign * (self.max_on(a, b) if sign > 0 else self.min_on(a, b)), self._raw(min(i0, len(self.t) - 1))
        f = self.f
        k = i0 + int(np.argmax(f[i0:i1]) if sign > 0 else np.argmin(f[i0:i1]))
        # The nodes' peak refined on the parabola through it and its neighbours; a and b (interpolated linearly
        # between nodes) on the parabola of their nearest inner node.
        ia, ib = (a - self.t0) / self.dt, (b - self.t0) / self.dt  # in node steps
        best, at, last = -math.inf, k, len(f) - 2
        for i, end in ((k, None), (round(ia), ia), (round(ib), ib)):
            i = min(max(i, i0, 1), i1 - 1, last)
            f0, f1, f2 = f[i - 1:i + 2].tolist()
            slope, curv = 0.5 * sign * (f2 - f0), 0.5 * sign * (f2 - 2.0 * f1 + f0)
            if end is None:
                d = min(max(-slope / (2.0 * curv) if curv < 0 else 0.0, -1.0, ia - i), 1.0, ib - i)
            else:
                d = end - i
            value = sign * f1 + slope * d + curv * d * d
            if value > best:
                best, at = value, i
        return max(best, sign * float(f[k])), self._raw(at)

    def _raw(self, i: int) -> float:
        """Raw pixels per normalized unit across the frame edge at node i."""
        return self.scale * abs(float(self.slope[i]))


class _Boundaries(NamedTuple):
    """The valid set's four boundary graphs: L(y) and R(y) (u = 0, u = W−1), T(x) and B(x) (v = 0, v = H−1)."""

    left: _Graph
    right: _Graph
    top: _Graph
    bottom: _Graph


def _boundaries(calib: Calibration, r_fold: float, nodes: int,
            box: tuple[float, float, float, float]) -> _Boundaries:
    """The four boundary graphs L(y), R(y), T(x), B(x) on `nodes` nodes over a box (x0, x1, y0, y1) holding the
    valid rectangles."""
    x0, x1, y0, y1 = box
    ys, xs = np.linspace(y0, y1, nodes), np.linspace(x0, x1, nodes)
    edges, rows = _edges(calib), [True, True, False, False]
    curves, slopes = _solve_axis(np.concatenate([ys, ys, xs, xs]), np.repeat(edges, nodes), np.repeat(rows, nodes),
                                 calib, r_fold)
    # Rectangles stay in the box: it bounds the curves where the frame edge is out of reach (or past max_fov).
    clips = [(np.maximum, x0), (np.minimum, x1), (np.maximum, y0), (np.minimum, y1)]

    def graph(t: np.ndarray, values: np.ndarray, side: int, scale: float) -> _Graph:
        """Boundary curve `side` (left, right, top, bottom) from its node values, clipped to the box."""
        clip, bound = clips[side]

        def solve(free: np.ndarray) -> np.ndarray:
            """The curve at any points, by the same Newton solve and clip as its nodes."""
            fixed = np.asarray(free, dtype=np.float64)
            return clip(_solve_axis(fixed, np.full_like(fixed, edges[side]), np.full(fixed.shape, rows[side]),
                                    calib, r_fold)[0], bound)

        return _Graph(t, clip(values, bound), solve, slopes[side * nodes:(side + 1) * nodes], scale)

    return _Boundaries(*(graph(ys if side < 2 else xs, curves[side * nodes:(side + 1) * nodes], side,
                               calib.fx if side < 2 else calib.fy) for side in range(4)))


def _largest(bounds: _Boundaries, aspect: float, calib: Calibration) -> tuple[float, float, float]:
    """(height s, centre xc, yc) of the largest rectangle the graphs' nodes allow, centred where it can slide."""
    # Start from a small rectangle around the principal point and grow s to the root of "spare = 0".
    s = 0.25 * min(bounds.left.t[-1] - bounds.left.t[0], (bounds.top.t[-1] - bounds.top.t[0]) / aspect)
    for _ in range(30):
        xc, yc, spare = _centre(s, aspect, bounds, 0.0, 0.0)
        if spare > 0:
            break
        s *= 0.5
    else:
        raise AppdgenError(f"calibration has no valid region around its principal point: {calib.to_dict()}")
    return _grow(bounds, aspect, s, xc, yc, spare, np.inf, -np.inf)


def _centre(s: float, aspect: float, bounds: _Boundaries, xc: float, yc: float) -> tuple[float, float, float]:
    """Centre a rectangle of height s (width aspect·s) between the curves from centre (xc, yc); → (xc, yc, spare: the
    slack left, normalized height units)."""
    left, right, top, bottom = bounds
    half_w, half_h = 0.5 * aspect * s, 0.5 * s
    for _ in range(100):
        lo_y, hi_y = top.max_on(xc - half_w, xc + half_w), bottom.min_on(xc - half_w, xc + half_w)
        if not (np.isfinite(lo_y) and np.isfinite(hi_y)):
            return xc, yc, -np.inf
        y_new = 0.5 * (lo_y + hi_y)
        lo_x, hi_x = left.max_on(y_new - half_h, y_new + half_h), right.min_on(y_new - half_h, y_new + half_h)
        if not (np.isfinite(lo_x) and np.isfinite(hi_x)):
            return xc, yc, -np.inf
        x_new = 0.5 * (lo_x + hi_x)
        done = abs(x_new - xc) < _TOL and abs(y_new - yc) < _TOL
        xc, yc = x_new, y_new
        if done:
            break
    return xc, yc, min((hi_x - lo_x) / aspect, hi_y - lo_y) - s


def _grow(bounds: _Boundaries, aspect: float, s: float, xc: float, yc: float, spare: float, hi: float,
          spare_hi: float) -> tuple[float, float, float]:
    """Grow a fitting rectangle of height s (slack `spare` ≥ 0) to the root of "spare = 0", below hi."""
    lo = s
    for _ in range(100):
        # The slack falls about one-for-one with s: step by it, or by regula falsi once bracketed.
        trial = s + spare if np.isinf(hi) else lo + spare * (hi - lo) / (spare - spare_hi)
        if not lo < trial < hi:
            trial = 0.5 * (lo + hi)
        txc, tyc, tspare = _centre(trial, aspect, bounds, xc, yc)
        if tspare >= 0:
            lo, s, xc, yc, spare = trial, trial, txc, tyc, tspare
        else:
            hi, spare_hi = trial, tspare
        if spare < _TOL or hi - lo < _TOL:
            break
    return s, xc, yc


def _grid_error(bounds: _Boundaries, aspect: float, s: float, xc: float, yc: float,
                calib: Calibration) -> tuple[float, float]:
    """About how far the nodes' crop is off the exact one: (output pixels at the raw size, either way; raw pixels
    by which its border leaves the frame, the guard's unit), to first order in the curves' errors between nodes."""
    nodes_crop = Crop.around(xc, yc, s, aspect)
    x0, x1, y0, y1 = nodes_crop.x0, nodes_crop.x1, nodes_crop.y0, nodes_crop.y1
    (left, raw_l), (right, raw_r) = bounds.left.curve_max(y0, y1, 1.0), bounds.right.curve_max(y0, y1, -1.0)
    (top, raw_t), (bottom, raw_b) = bounds.top.curve_max(x0, x1, 1.0), bounds.bottom.curve_max(x0, x1, -1.0)
    right, bottom = -right, -bottom
    # The rectangle the curves' extrema would give: the largest between them, centred there.
    s_new = min((right - left) / aspect, bottom - top)
    half_w, half_h, mid_x, mid_y = 0.5 * aspect * s_new, 0.5 * s_new, 0.5 * (left + right), 0.5 * (top + bottom)
    out_x, out_y = calib.width / (x1 - x0), calib.height / (y1 - y0)  # output px per normalized unit
    output_error = max(abs(mid_x - half_w - x0) * out_x, abs(mid_x + half_w - x1) * out_x,
                       abs(mid_y - half_h - y0) * out_y, abs(mid_y + half_h - y1) * out_y)
    # Where a curve passes its edge of the rectangle, by how many raw pixels.
    excess = max((left - x0) * raw_l, (x1 - right) * raw_r, (top - y0) * raw_t, (y1 - bottom) * raw_b)
    return output_error, excess


def _off_by_more(errors: tuple[float, float], fine: float) -> bool:
    """Whether _grid_error's (output px, raw excess px) pass GRID_ERROR_PX or GRID_EXCESS_PX, times `fine`."""
    return errors[0] > GRID_ERROR_PX * fine or errors[1] > GRID_EXCESS_PX * fine


def _nodes_region(calib: Calibration, nodes: int,
                  box: tuple[float, float, float, float]) -> tuple[Crop, _Boundaries]:
    """R on the nodes alone (no exactness pass, no guard) over a box, and its graphs."""
    r_fold = radial_fold_radius(calib)
    bounds = _boundaries(calib, r_fold, nodes, box)
    aspect = _aspect(calib)
    s, xc, yc = _largest(bounds, aspect, calib)
    return Crop.around(xc, yc, s, aspect), bounds


def _slide_box_of(bounds: _Boundaries, crop: Crop) -> tuple[float, float, float, float]:
    """Where the boundary curves bind around a crop: (max L, min R) over its rows, (max T, min B) over its columns."""
    return (bounds.left.max_on(crop.y0, crop.y1), bounds.right.min_on(crop.y0, crop.y1),
            bounds.top.max_on(crop.x0, crop.x1), bounds.bottom.min_on(crop.x0, crop.x1))


def _check_crop(calib: Calibration, crop: Crop, r_fold: float) -> None:
    """Guard: R's border maps inside the frame and the lens is monotone over R (else AppdgenError)."""
    corners = np.hypot([crop.x0, crop.x1, crop.x0, crop.x1], [crop.y0, crop.y0, crop.y1, crop.y1])
    if max(corners) >= r_fold * (1 - 1e-4):  # touching the fold circle, to grid accuracy
        raise _fold_error(calib, r_fold)
    t = np.linspace(0.0, 1.0, 512)
    x = np.concatenate([crop.x0 + t * (crop.x1 - crop.x0)] * 2 + [np.full_like(t, crop.x0), np.full_like(t, crop.x1)])
    y = np.concatenate([np.full_like(t, crop.y0), np.full_like(t, crop.y1)] + [crop.y0 + t * (crop.y1 - crop.y0)] * 2)
    u, v = distort_to_pixels(x, y, calib)
    tol = 1e-3  # pixels: far below the 0.01-pixel accuracy promised, far above the grid error
    inside = (u >= -tol) & (u <= calib.width - 1 + tol) & (v >= -tol) & (v <= calib.height - 1 + tol)
    gx, gy = np.meshgrid(np.linspace(crop.x0, crop.x1, 33), np.linspace(crop.y0, crop.y1, 33))
    dxx, dxy, dyx, dyy = distortion_jacobian(gx, gy, calib)
    if (dxx <= 0).any() or (dyy <= 0).any() or (dxx * dyy - dxy * dyx <= 0).any():
        raise _fold_error(calib, r_fold)
    if not inside.all():
        raise AppdgenError(f"internal error: valid region {crop} leaves the frame for calibration {calib.to_dict()}")


def _fold_error(calib: Calibration, r_fold: float) -> AppdgenError:
    """The error for a lens that is not one-to-one where the crop needs it."""
    return AppdgenError(
        f"distortion folds over inside the {calib.width}x{calib.height} frame (the {calib.model} model stops being "
        f"one-to-one at r={r_fold:.4g}, where the crop needs it): "
        + " ".join(f"{n}={v:g}" for n, v in zip(calib.param_names[4:], calib.coeffs, strict=True))
    )


def _solve_axis(fixed: np.ndarray, target: np.ndarray, rows: np.ndarray, calib: Calibration,
                r_fold: float) -> tuple[np.ndarray, np.ndarray]:
    """Free coordinate t per element: x with m_x(t, fixed) = target where `rows`, else y with m_y(fixed, t) = target;
    and the slope ∂m/∂t there (unitless; meaningless where no root was found).

    One vectorized Newton loop on the model's projection along one axis solves all four boundary curves. Where no
    root lies inside the fold radius the frame edge is never reached there, and the fold circle bounds the set.
    """
    along, coeffs = _axis_projection(lens.get(calib.model)), calib.coeffs
    t, dm = target.copy(), np.ones_like(target)
    # The points still moving, packed: (their index, t, fixed, rows, target).
    index, ta, fa, ra, ga = np.arange(t.size), t.copy(), fixed, rows, target
    with np.errstate(all="ignore"):  # diverging points turn non-finite, leave the active set, and are caught below
        for _ in range(NEWTON_STEPS):
            # From the distorted value Newton converges in ~6 steps where a root exists (more far out in a
            # fisheye); iterating only on the points still moving keeps those with no root from costing every step.
            m, slope = along(ta, fa, ra, coeffs)
            step = m - ga
            step /= slope
            ta = ta - step
            moving = np.abs(step) > 1e-13  # ~1e-10 px: converged (smaller steps are rounding jitter)
            if not moving.all():
                t[index], dm[index] = ta, slope
                index, ta, fa, ra, ga = index[moving], ta[moving], fa[moving], ra[moving], ga[moving]
                slope = slope[moving]
                if index.size == 0:
                    break
        t[index] = ta
        dm[index] = slope
        # The root test needs no slope: the plain projection spares a generic model its Jacobian here.
        mx, my = lens.get(calib.model).project(*_plane(t, fixed, rows), coeffs)
        missing = ~((np.abs(np.where(rows, mx, my) - target) < 1e-12) & (t * t + fixed * fixed < r_fold * r_fold))
        t[missing] = np.copysign(np.sqrt(np.maximum(r_fold * r_fold - fixed[missing] ** 2, 0.0)), target[missing])
    return t, dm


def _axis_projection(model):
    """The model's project_axis (m along the free coordinate t, and dm/dt), or one built from project and jacobian."""
    if hasattr(model, "project_axis"):
        return model.project_axis

    def project_axis(t: np.ndarray, fixed: np.ndarray, rows: np.ndarray, coeffs: tuple[float, ...]):
        x, y = _plane(t, fixed, rows)
        mx, my = model.project(x, y, coeffs)
        dxx, _, _, dyy = model.jacobian(x, y, coeffs)
        return np.where(rows, mx, my), np.where(rows, dxx, dyy)

    return project_axis


def _plane(t: np.ndarray, fixed: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the free coordinate t and the fixed one: x = t along rows, y = t along columns."""
    return np.where(rows, t, fixed), np.where(rows, fixed, t)


def _parabola_peaks(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Peaks of the parabolas through each local maximum of f(t) (sorted t, ends included) and its neighbours,
    where they may rise above max f; clipped to the neighbours' span."""
    n = t.size
    if n < 3:
        return np.array([0.5 * (t[0] + t[-1])])
    k = np.flatnonzero((f >= np.concatenate([[-np.inf], f[:-1]])) & (f >= np.concatenate([f[1:], [-np.inf]])))
    j = np.clip(k, 1, n - 2)
    x0, x1, x2, y0, y1, y2 = t[j - 1], t[j], t[j + 1], f[j - 1], f[j], f[j + 1]
    d1 = (y1 - y0) / (x1 - x0)
    c = ((y2 - y1) / (x2 - x1) - d1) / (x2 - x0)
    with np.errstate(divide="ignore", invalid="ignore"):
        peak = np.clip(0.5 * (x0 + x1) - d1 / (2.0 * c), t[np.maximum(k - 1, 0)], t[np.minimum(k + 1, n - 1)])
    rise = y0 + d1 * (peak - x0) + c * (peak - x0) * (peak - x1) - f.max()
    # Twice the predicted rise: a peak a little under the nodes' max by the parabola may still top it.
    keep = (c < 0) & (rise + (rise + f.max() - f[k]) > 0)
    return peak[keep]


def _bounded_box(calib: Calibration, r_fold: float, max_fov: float | None) -> tuple[float, float, float, float]:
    """_frame_box cut to the max_fov box (fov_box); AppdgenError if it is still unbounded."""
    x0, x1, y0, y1 = _fov_cut(calib, _frame_box(calib, r_fold, max_fov is not None), max_fov)
    if not np.isfinite([x0, x1, y0, y1]).all():
        raise AppdgenError(f"the frame's axes never leave the {calib.model} lens's valid region, so it is unbounded: "
                           "bound the view with --max-fov DEG, e.g. --max-fov 120")
    return x0, x1, y0, y1


def _frame_box(calib: Calibration, r_fold: float, bounded: bool) -> tuple[float, float, float, float]:
    """A box (x0, x1, y0, y1), normalized, holding the valid rectangles: the frame border's, or the axes' extent.

    `bounded`: a max_fov box will cut the result, so a lens that sees past 90° is no error here.
    """
    x, y = undistort_pixels(*_border_pixels(calib, 17), calib, iterations=12, on_failure="nan")
    ok = np.isfinite(x) & (np.hypot(x, y) < r_fold)
    if not ok.all() and np.isfinite(r_fold):
        # Part of the border lies beyond the fold: the fold circle then bounds the valid set there.
        return (-r_fold, r_fold, -r_fold, r_fold)
    if not ok.all():
        # Nothing folds, yet part of the border does not undistort (the kodak file's tangential terms fold its
        # corners; a fisheye's corners may be past 90°): a rectangle around the principal point is then bounded
        # by where the axes through it leave the frame.
        if not bounded:
            _refuse_unbounded(calib)
        (left, right, top, bottom), _ = _solve_axis(np.zeros(4), np.array(_edges(calib)),
                                               np.array([True, True, False, False]), calib, r_fold)
        return (left, right, top, bottom)
    # A 2 % margin covers the border's bulge between the 17 samples a side.
    pad_x, pad_y = 0.02 * (x.max() - x.min()), 0.02 * (y.max() - y.min())
    return (max(x.min() - pad_x, -r_fold), min(x.max() + pad_x, r_fold),
            max(y.min() - pad_y, -r_fold), min(y.max() + pad_y, r_fold))


def _refuse_unbounded(calib: Calibration) -> None:
    """AppdgenError when some frame pixel sees 90° or more off-axis: the valid set then holds unbounded sectors."""
    # Directions at 90° that land inside the frame are the limit of points ever further out in the plane, so
    # arbitrarily large rectangles fit around them and "the largest rectangle" does not exist.
    u, v = _border_pixels(calib, 257)
    _, _, z = pixel_rays(u, v, calib)
    past = np.flatnonzero(z <= 0)
    if past.size:
        i = past[np.argmin(z[past])]
        raise AppdgenError(
            f"the {calib.model} lens sees {np.degrees(np.arccos(z[i])):.0f}° off-axis inside its {calib.width}x"
            f"{calib.height} frame (raw pixel ({u[i]:.0f}, {v[i]:.0f})), so its valid region is unbounded: bound "
            "the view with --max-fov DEG, e.g. --max-fov 120")


def _fov_cut(calib: Calibration, box: tuple[float, float, float, float],
             max_fov: float | None) -> tuple[float, float, float, float]:
    """A box (x0, x1, y0, y1), normalized, cut to the max_fov box (fov_box); as it is when max_fov is None."""
    if max_fov is None:
        return box
    half_x, half_y = fov_box(calib, max_fov)
    return max(box[0], -half_x), min(box[1], half_x), max(box[2], -half_y), min(box[3], half_y)


def _border_pixels(calib: Calibration, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions along the raw frame's border [0, W−1] × [0, H−1], `samples` per side."""
    s = np.linspace(0.0, 1.0, samples)
    w, h = calib.width - 1.0, calib.height - 1.0
    u = np.concatenate([s * w, np.full_like(s, w), s * w, np.zeros_like(s)])
    v = np.concatenate([np.zeros_like(s), s * h, np.full_like(s, h), s * h])
    return u, v


def _edges(calib: Calibration) -> list[float]:
    """The frame's edges u = 0, u = W−1, v = 0, v = H−1 as distorted normalized coordinates."""
    return [-calib.cx / calib.fx, (calib.width - 1 - calib.cx) / calib.fx,
            -calib.cy / calib.fy, (calib.height - 1 - calib.cy) / calib.fy]


def _aspect(calib: Calibration) -> float:
    """Width over height of a raw-aspect rectangle in normalized units (square output pixels ↔ raw pixels)."""
    return (calib.width / calib.height) * (calib.fy / calib.fx)
