"""The calibration type: image size, pinhole intrinsics and one lens model's coefficients, immutable and validated."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from appdgen import lens
from appdgen.errors import AppdgenError

#: The pinhole intrinsics every model shares (pixels).
INTRINSICS: tuple[str, ...] = ("fx", "fy", "cx", "cy")
FOCAL = ("fx", "fy")
PRINCIPAL = ("cx", "cy")
DEFAULT_MODEL = "radtan"
#: The radial-tangential model's coefficients and its nine parameters (OpenCV's order of K then D).
DISTORTION: tuple[str, ...] = lens.params(DEFAULT_MODEL)
PARAMS: tuple[str, ...] = (*INTRINSICS, *DISTORTION)
#: Models whose coefficients come as OpenCV's distortion vector (4, 5, 8, 12 or 14 long), and the sizes they take.
OPENCV_SIZES: dict[str, str] = {"radtan": "4 or 5", "rational": "4, 5, 8 or 12"}


@dataclass(frozen=True, init=False)
class Calibration:
    """Θ: raw image size (pixels), K entries (pixels), lens model name and its coefficients (unitless).

    ``Calibration(w, h, fx, fy, cx, cy, k1, k2, p1, p2, k3)`` is radial-tangential as before; other models take
    ``model=`` and their coefficients positionally or by name (``Calibration(w, h, fx, fy, cx, cy, model="ds",
    xi=-0.2, alpha=0.6)``); coefficients not given are 0. A coefficient reads as an attribute (``calib.k1``).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str
    coeffs: tuple[float, ...]

    def __init__(self, width: int, height: int, fx: float, fy: float, cx: float, cy: float, *args: float,
                 model: str = DEFAULT_MODEL, coeffs: tuple[float, ...] | None = None, **named: float) -> None:
        names = lens.params(model)
        if coeffs is not None and (args or named):
            raise AppdgenError("calibration: give coefficients either as coeffs= or by position/name, not both")
        values = list(coeffs if coeffs is not None else args)
        if len(values) > len(names):
            raise AppdgenError(f"calibration: lens model {model!r} has {len(names)} coefficients "
                               f"({', '.join(names)}), got {len(values)}")
        values += [0.0] * (len(names) - len(values))
        for name, value in named.items():
            if name not in names:
                raise AppdgenError(f"calibration: {name!r} is not a coefficient of lens model {model!r} "
                                   f"({', '.join(names)})")
            values[names.index(name)] = value
        for field, value in (("width", width), ("height", height), ("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
            object.__setattr__(self, field, value)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "coeffs", tuple(_finite(n, v) for n, v in zip(names, values, strict=True)))
        self._validate()
        lens.get(model).validate(self.coeffs)

    def _validate(self) -> None:
        """Sizes are integers > 1, intrinsics finite numbers, focal lengths positive."""
        for name in ("width", "height"):
            value = getattr(self, name)
            try:
                whole = not isinstance(value, bool) and int(value) == value
            except (TypeError, ValueError, OverflowError):  # None, NaN, inf, lists…
                whole = False
            if not whole or value <= 1:
                raise AppdgenError(f"calibration: {name} must be an integer > 1, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in INTRINSICS:
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.fx <= 0 or self.fy <= 0:
            raise AppdgenError(f"calibration: focal lengths must be positive, got fx={self.fx!r} fy={self.fy!r}")

    def __getattr__(self, name: str) -> float:
        # Only reached when normal lookup fails: a coefficient of this calibration's model, by name.
        if name.startswith("__") or name in ("model", "coeffs"):
            raise AttributeError(name)
        names = lens.params(self.model)
        if name in names:
            return self.coeffs[names.index(name)]
        raise AttributeError(f"{type(self).__name__} ({self.model}) has no attribute {name!r}")

    @classmethod
    def from_arrays(cls, width: int, height: int, K: np.ndarray, D: np.ndarray | None = None,
                    model: str = DEFAULT_MODEL) -> "Calibration":
        """Build from a 3×3 camera matrix (pixels) and a model's coefficients in order (OpenCV's vector for radtan:
        4 or 5, for rational: 4, 5, 8 or 12; a 14-long vector with non-zero tilt is refused)."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise AppdgenError(f"calibration: camera matrix must be 3x3, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
            raise AppdgenError(f"calibration: skewed camera matrix (K[0,1]={K[0, 1]!r}) is not supported")
        d = np.zeros(0) if D is None else np.asarray(D, dtype=float).ravel()
        if model in OPENCV_SIZES:
            if d.size not in (0, 4, 5, 8, 12, 14):
                raise AppdgenError(f"calibration: expected {OPENCV_SIZES[model]} distortion coefficients, got {d.size}")
            if d.size == 14 and np.any(d[12:] != 0):
                lens.get("tilted")  # refused with the reason
            kept = len(lens.params(model))
            if np.any(d[kept:] != 0):
                raise AppdgenError("calibration: rational/thin-prism distortion (coefficients past k3) needs "
                                   "model='rational'")
            d = d[:kept]
        return cls(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d.tolist(), model=model)

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
        """The model's coefficients as an array (for radtan OpenCV's distortion vector k1, k2, p1, p2, k3)."""
        return np.array(self.coeffs, dtype=np.float64)

    @property
    def param_names(self) -> tuple[str, ...]:
        """fx, fy, cx, cy, then the model's coefficient names."""
        return (*INTRINSICS, *lens.params(self.model))

    @property
    def diagonal(self) -> float:
        """Raw image diagonal √(W²+H²) in pixels: the unit of APPD percentages."""
        return math.hypot(self.width, self.height)

    def params(self) -> dict[str, float]:
        """The parameters by name: intrinsics (pixels), then the model's coefficients."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                **dict(zip(lens.params(self.model), self.coeffs, strict=True))}

    def to_dict(self) -> dict[str, Any]:
        """Size, model and parameters as a flat JSON-ready dict."""
        return {"width": self.width, "height": self.height, "model": self.model, **self.params()}

    def replace(self, **changes: Any) -> "Calibration":
        """A copy with some parameters (or width, height) set to new values (validated)."""
        unknown = set(changes) - set(self.param_names) - {"width", "height"}
        if unknown:
            raise AppdgenError(f"unknown calibration parameter(s) {sorted(unknown)}; expected one of "
                               f"{list(self.param_names)}")
        values = {**self.params(), **changes}
        coeffs = tuple(values[n] for n in lens.params(self.model))
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if k in ("width", "height", *INTRINSICS)},
                                   coeffs=coeffs)

    def perturb(self, **fractions: float) -> "Calibration":
        """A copy with parameters multiplied by (1 + fraction), e.g. perturb(fx=0.05) → fx × 1.05."""
        unknown = set(fractions) - set(self.param_names)
        if unknown:
            raise AppdgenError(f"unknown calibration parameter(s) {sorted(unknown)}; expected one of "
                               f"{list(self.param_names)}")
        return self.replace(**{n: getattr(self, n) * (1.0 + f) for n, f in fractions.items()})


def _finite(name: str, value: Any) -> float:
    """value as a finite float, else AppdgenError naming the parameter."""
    try:
        value = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: ints past 1e308
        raise AppdgenError(f"calibration: {name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise AppdgenError(f"calibration: {name} must be finite, got {value!r}")
    return value
