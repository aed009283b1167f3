"""Sampling perturbed calibrations whose APPD labels are about uniform over [0, appd_max] (% of the diagonal).

Each sample draws its target APPD first, then a random direction in the parameter box (extended to the box's
boundary), and solves for the scale along that ray whose APPD hits the target (regula falsi, Illinois variant,
on [0, 1] where APPD(0) = 0). Directions that cannot reach the target inside the box are redrawn. The search
evaluates APPD on a coarse output grid (midpoint rule) with a coarser crop; the stored label is later computed
on the full output grid. All randomness of sample i comes from numpy's SeedSequence([seed, i]).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from appdgen.calibration import DISTORTION, FOCAL, PARAMS, PRINCIPAL, Calibration
from appdgen.crop import valid_region
from appdgen.distortion import distort_to_pixels
from appdgen.errors import AppdgenError

#: The paper's ranges: (low, high) as fractions of the reference value.
PAPER_RANGES: dict[str, tuple[float, float]] = {
    **{name: (-0.05, 0.20) for name in FOCAL},
    **{name: (-0.05, 0.05) for name in PRINCIPAL},
    **{name: (-0.15, 0.15) for name in DISTORTION},
}
DEFAULT_APPD_MAX = 1.0  # % of the raw diagonal
SEARCH_NODES = 257  # crop grid of the search: ~1e-4 px, a third of the full crop's cost
COARSE_COLUMNS = 48  # coarse output grid of the search: 48 × 18 for KITTI


@dataclass(frozen=True)
class Range:
    """Allowed change of one parameter: [low, high] as a fraction of the reference (relative) or in its units."""

    low: float
    high: float
    relative: bool = True

    def offsets(self, value: float) -> tuple[float, float]:
        """(low, high) change in the parameter's own units for a reference value."""
        return (self.low * abs(value), self.high * abs(value)) if self.relative else (self.low, self.high)

    def describe(self) -> str:
        """'-5%:20%' or '-0.01:0.01' as the CLI spells it."""
        if self.relative:
            return f"{self.low * 100:g}%:{self.high * 100:g}%"
        return f"{self.low:g}:{self.high:g}"


def paper_ranges() -> dict[str, Range]:
    """The paper's ranges: focal −5 %…+20 %, principal point ±5 %, distortion ±15 % (relative)."""
    return {name: Range(lo, hi) for name, (lo, hi) in PAPER_RANGES.items()}


def parse_ranges(text: str | None, base: dict[str, Range] | None = None) -> dict[str, Range]:
    """'fx=-5%:20%,k3=-0.01:0.01' over the defaults; '%' marks relative bounds, bare numbers absolute units."""
    ranges = dict(base or paper_ranges())
    for item in filter(None, (part.strip() for part in (text or "").split(","))):
        name, sep, spec = item.partition("=")
        low_text, colon, high_text = spec.partition(":")
        if name not in PARAMS or not sep or not colon:
            raise AppdgenError(f"--ranges {item!r}: expected NAME=LOW:HIGH with NAME one of {', '.join(PARAMS)}")
        relative = low_text.strip().endswith("%") and high_text.strip().endswith("%")
        if relative != (low_text.strip().endswith("%") or high_text.strip().endswith("%")):
            raise AppdgenError(f"--ranges {item!r}: give both bounds in % (relative) or both in units (absolute)")
        try:
            low, high = (float(t.strip().rstrip("%")) for t in (low_text, high_text))
        except ValueError:
            raise AppdgenError(f"--ranges {item!r}: bounds must be numbers") from None
        if not (math.isfinite(low) and math.isfinite(high)) or low > high or low > 0 or high < 0:
            raise AppdgenError(f"--ranges {item!r}: need LOW <= 0 <= HIGH (the reference must lie in the range)")
        ranges[name] = Range(low / 100, high / 100, True) if relative else Range(low, high, False)
    return ranges


@dataclass(frozen=True)
class Draw:
    """One sampled calibration with its search bookkeeping (target and estimate in % of the diagonal)."""

    index: int
    calib: Calibration
    is_reference: bool
    target_pct: float
    estimate_pct: float
    evaluations: int
    seconds: float


@dataclass
class Sampler:
    """Draws calibrations around a reference so that APPD labels are about uniform over [0, appd_max]."""

    reference: Calibration
    ranges: dict[str, Range] = field(default_factory=paper_ranges)
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = 0.01
    size: tuple[int, int] | None = None
    tolerance: float = 0.01  # of appd_max: a fifth of a 5 % histogram bin
    max_directions: int = 200

    def __post_init__(self) -> None:
        if not (self.appd_max > 0 and math.isfinite(self.appd_max)):
            raise AppdgenError(f"--appd-max {self.appd_max!r}: must be a positive number (% of the diagonal)")
        if not 0 <= self.zero_fraction <= 1:
            raise AppdgenError(f"--zero-fraction {self.zero_fraction!r}: must be in [0, 1]")
        values = np.array([getattr(self.reference, n) for n in PARAMS])
        bounds = [self.ranges[n].offsets(v) for n, v in zip(PARAMS, values)]
        self._base = values
        self._low = np.array([b[0] for b in bounds])
        self._high = np.array([b[1] for b in bounds])
        if not (self._high - self._low > 0).any():
            raise AppdgenError("--ranges: every range is empty, so no perturbation is possible")
        w, h = self.size or self.reference.size
        cols = COARSE_COLUMNS
        rows = max(8, round(cols * h / w))
        # Cell centres of a cols × rows partition of the output image, in output pixels (midpoint rule).
        self._grid = np.meshgrid((np.arange(cols) + 0.5) * w / cols - 0.5, (np.arange(rows) + 0.5) * h / rows - 0.5)
        self._out_size = (w, h)
        self._ref_points = self._positions(self.reference)
        self._jacobian = self._position_jacobian()

    def _position_jacobian(self) -> np.ndarray:
        """∂(coarse M̂ positions)/∂(parameter) at the reference, by forward differences (9 × 2 × rows × cols)."""
        jacobian = np.zeros((len(PARAMS), *self._ref_points.shape))
        for j, width in enumerate(self._high - self._low):
            if width > 0:
                step = np.zeros(len(PARAMS))
                step[j] = 1e-3 * width
                jacobian[j] = (self._positions(self._calibration(step)) - self._ref_points) / step[j]
        return jacobian

    def _first_guess(self, direction: np.ndarray, edge_pct: float, target: float) -> float:
        """Scale λ where APPD(λ) ≈ g·λ + (f(1) − g)·λ² meets the target, g = APPD's slope at λ = 0 (% / unit λ)."""
        slope = np.hypot(*np.tensordot(direction, self._jacobian, axes=1)).mean() * 100.0 / self.reference.diagonal
        curve = edge_pct - slope
        if abs(curve) < 1e-12:
            return target / slope
        disc = slope * slope + 4.0 * curve * target
        lam = (-slope + np.sqrt(disc)) / (2.0 * curve) if disc >= 0 else -1.0
        return float(lam) if 0.0 < lam < 1.0 else target / edge_pct

    def zero_ranges(self) -> list[str]:
        """Parameters whose range is empty (e.g. relative ranges around a reference value of 0)."""
        return [n for n, lo, hi in zip(PARAMS, self._low, self._high) if lo == hi == 0]

    def _positions(self, calib: Calibration, check: bool = True) -> np.ndarray:
        """Raw-pixel positions of M̂ at the coarse grid (2 × rows × cols)."""
        k = valid_region(calib, SEARCH_NODES, check).camera_matrix(self._out_size)
        gx, gy = self._grid
        return np.stack(distort_to_pixels((gx - k[0, 2]) / k[0, 0], (gy - k[1, 2]) / k[1, 1], calib))

    def estimate(self, calib: Calibration, check: bool = True) -> float:
        """APPD (% of the diagonal) against the reference on the coarse grid."""
        distance = np.hypot(*(self._positions(calib, check) - self._ref_points))
        return float(distance.mean()) * 100.0 / self.reference.diagonal

    def _calibration(self, offsets: np.ndarray) -> Calibration:
        """The reference moved by parameter offsets (parameter units)."""
        return self.reference.replace(**dict(zip(PARAMS, (self._base + offsets).tolist())))

    def _direction(self, rng: np.random.Generator) -> np.ndarray:
        """A uniform point of the box, pushed out along its ray to the box's boundary (parameter units)."""
        d = rng.uniform(self._low, self._high)
        reach = np.where(d > 0, d / np.where(self._high > 0, self._high, 1), d / np.where(self._low < 0, self._low, -1))
        return d / reach.max() if reach.max() > 0 else d

    def draw(self, seed: int, index: int) -> Draw:
        """Sample `index` of a build with this seed: the same calibration whatever the worker or order."""
        start = time.perf_counter()
        rng = np.random.default_rng([seed, index])
        if rng.random() < self.zero_fraction:
            return Draw(index, self.reference, True, 0.0, 0.0, 0, time.perf_counter() - start)
        target = rng.uniform(0.0, self.appd_max)
        evaluations = 0
        for _ in range(self.max_directions):
            direction = self._direction(rng)
            found, used = self._solve(direction, target)
            evaluations += used
            if found is not None and self._is_valid(found[0]):
                calib, estimate = found
                return Draw(index, calib, False, target, estimate, evaluations, time.perf_counter() - start)
        raise AppdgenError(
            f"--appd-max {self.appd_max:g}: after {self.max_directions} directions none reached APPD "
            f"{target:.3f} % inside the ranges; lower --appd-max or widen --ranges"
        )

    @staticmethod
    def _is_valid(calib: Calibration) -> bool:
        """Whether the search's answer passes the crop's full guard (the searches skip it)."""
        try:
            valid_region(calib, SEARCH_NODES)
            return True
        except AppdgenError:
            return False

    def _evaluate(self, offsets: np.ndarray) -> tuple[Calibration, float] | None:
        """(calibration, coarse APPD %) for offsets, or None when that calibration is invalid (fold-over)."""
        try:
            calib = self._calibration(offsets)
            return calib, self.estimate(calib, check=False)
        except AppdgenError:
            return None

    def _solve(self, direction: np.ndarray, target: float) -> tuple[tuple[Calibration, float] | None, int]:
        """Scale along the ray whose coarse APPD is the target (Illinois regula falsi); None when out of reach."""
        edge = self._evaluate(direction)
        if edge is None or edge[1] < target:
            return None, 1
        a, fa, b, fb = 0.0, -target, 1.0, edge[1] - target
        best, evaluations, side = edge, 1, 0
        tolerance = self.tolerance * self.appd_max
        lam = self._first_guess(direction, edge[1], target)
        while abs(best[1] - target) > tolerance and evaluations < 30:
            point = self._evaluate(lam * direction)
            evaluations += 1
            if point is None:
                return None, evaluations
            best, f = point, point[1] - target
            if f * fb > 0:
                b, fb = lam, f
                fa, side = (fa / 2, side) if side == -1 else (fa, -1)
            else:
                a, fa = lam, f
                fb, side = (fb / 2, side) if side == 1 else (fb, 1)
            lam = b - fb * (b - a) / (fb - fa)
        return best, evaluations
