"""The calibration type: a pinhole + radial-tangential camera, immutable and validated."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from appdgen.errors import AppdgenError

#: The nine intrinsic parameters, in OpenCV's order of K then D = (k1, k2, p1, p2, k3).
PARAMS: tuple[str, ...] = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
FOCAL = ("fx", "fy")
PRINCIPAL = ("cx", "cy")
DISTORTION = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Calibration:
    """Θ: raw image size (pixels), K entries (pixels) and distortion (k1, k2, p1, p2, k3; unitless)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            try:
                whole = not isinstance(value, bool) and int(value) == value
            except (TypeError, ValueError, OverflowError):  # None, NaN, inf, lists…
                whole = False
            if not whole or value <= 1:
                raise AppdgenError(f"calibration: {name} must be an integer > 1, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in PARAMS:
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError, OverflowError):  # OverflowError: ints past 1e308
                raise AppdgenError(f"calibration: {name} must be a number, got {value!r}") from None
            if not math.isfinite(value):
                raise AppdgenError(f"calibration: {name} must be finite, got {value!r}")
            object.__setattr__(self, name, value)
        if self.fx <= 0 or self.fy <= 0:
            raise AppdgenError(f"calibration: focal lengths must be positive, got fx={self.fx!r} fy={self.fy!r}")

    @classmethod
    def from_arrays(cls, width: int, height: int, K: np.ndarray, D: np.ndarray | None = None) -> "Calibration":
        """Build from a 3×3 camera matrix (pixels) and 0, 4, 5 or more OpenCV distortion coefficients."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise AppdgenError(f"calibration: camera matrix must be 3x3, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
            raise AppdgenError(f"calibration: skewed camera matrix (K[0,1]={K[0, 1]!r}) is not supported")
        d = np.zeros(5) if D is None else np.asarray(D, dtype=float).ravel()
        if d.size not in (0, 4, 5, 8, 12, 14):
            raise AppdgenError(f"calibration: expected 4 or 5 distortion coefficients, got {d.size}")
        if d.size > 5 and np.any(d[5:] != 0):
            raise AppdgenError("calibration: rational/thin-prism distortion (coefficients past k3) is not supported")
        d = np.concatenate([d, np.zeros(5)])[:5]
        return cls(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d)

    @property
    def size(self) -> tuple[int, int]:
        """Raw image size (width, height) in pixels."""
        return (self.width, self.height)

    @property
    def K(self) -> np.ndarray:
        """3×3 camera matrix in pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        """OpenCV distortion vector (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def diagonal(self) -> float:
        """Raw image diagonal √(W²+H²) in pixels: the unit of APPD percentages."""
        return math.hypot(self.width, self.height)

    def params(self) -> dict[str, float]:
        """The nine parameters by name."""
        return {name: getattr(self, name) for name in PARAMS}

    def to_dict(self) -> dict[str, float | int]:
        """Size and parameters as a flat JSON-ready dict."""
        return {"width": self.width, "height": self.height, **self.params()}

    def replace(self, **changes: float) -> "Calibration":
        """A copy with some parameters set to new values (validated)."""
        unknown = set(changes) - set(PARAMS) - {"width", "height"}
        if unknown:
            raise AppdgenError(f"unknown calibration parameter(s) {sorted(unknown)}; expected one of {list(PARAMS)}")
        return dataclasses.replace(self, **changes)

    def perturb(self, **fractions: float) -> "Calibration":
        """A copy with parameters multiplied by (1 + fraction), e.g. perturb(fx=0.05) → fx × 1.05."""
        unknown = set(fractions) - set(PARAMS)
        if unknown:
            raise AppdgenError(f"unknown calibration parameter(s) {sorted(unknown)}; expected one of {list(PARAMS)}")
        return self.replace(**{n: getattr(self, n) * (1.0 + f) for n, f in fractions.items()})
