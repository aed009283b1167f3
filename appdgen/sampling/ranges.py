"""The parameter box a sampler draws in: each parameter's allowed change (Range), the paper's and the per-model
default ranges, the CLI's --ranges syntax, and the box of offsets around a reference they span (ParameterBox)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from appdgen.calib.calibration import DEFAULT_MODEL, DISTORTION, FOCAL, PRINCIPAL, Calibration
from appdgen.errors import AppdgenError

#: The paper's ranges for the radtan model: (low, high) as fractions of the reference value.
PAPER_RANGES: dict[str, tuple[float, float]] = {
    **{name: (-0.05, 0.20) for name in FOCAL},
    **{name: (-0.05, 0.05) for name in PRINCIPAL},
    **{name: (-0.15, 0.15) for name in DISTORTION},
}
COEFFICIENT_RANGE = (-0.15, 0.15)  # relative, for every non-zero lens coefficient
#: Absolute (low, high) bounds for a lens coefficient whose reference value is 0, per model (radtan keeps the
#: paper's rule: a relative range around 0 is empty). About 15 % of a typical calibrated value, signs kept
#: where the model needs them (ds/eucm alpha ≥ 0, eucm beta > 0).
ZERO_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "rational": {**{k: (-0.01, 0.01) for k in ("k1", "k2", "k3", "k4", "k5", "k6")},
                 **{k: (-0.001, 0.001) for k in ("p1", "p2", "s1", "s2", "s3", "s4")}},
    "kb4": {k: (-0.001, 0.001) for k in ("k1", "k2", "k3", "k4")},
    "ds": {"xi": (-0.05, 0.05), "alpha": (0.0, 0.05)},
    "eucm": {"alpha": (0.0, 0.05), "beta": (0.0, 0.15)},
}


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
    """The paper's ranges (radtan): focal −5 %…+20 %, principal point ±5 %, distortion ±15 % (relative)."""
    return {name: Range(lo, hi) for name, (lo, hi) in PAPER_RANGES.items()}


def default_ranges(reference: Calibration) -> dict[str, Range]:
    """Default ranges over a reference's parameters: focal −5 %…+20 %, principal point ±5 %, non-zero coefficients
    ±15 % (relative); zero coefficients ZERO_RANGES of their model (absolute; radtan: none, as the paper)."""
    if reference.model == DEFAULT_MODEL:
        return paper_ranges()
    zero = ZERO_RANGES.get(reference.model, {})
    ranges = {name: Range(*PAPER_RANGES[name]) for name in (*FOCAL, *PRINCIPAL)}
    for name, value in zip(reference.param_names[4:], reference.coeffs, strict=True):
        ranges[name] = Range(*COEFFICIENT_RANGE) if value != 0 or name not in zero else Range(*zero[name], False)
    return ranges


def parse_ranges(text: str | None, reference: Calibration | None = None,
                 base: dict[str, Range] | None = None) -> dict[str, Range]:
    """'fx=-5%:20%,k3=-0.01:0.01' over the defaults; '%' marks relative bounds, bare numbers absolute units.

    Names are the reference's parameters (radtan's when no reference is given).
    """
    ranges = dict(base or (default_ranges(reference) if reference is not None else paper_ranges()))
    names = reference.param_names if reference is not None else tuple(PAPER_RANGES)
    for item in filter(None, (part.strip() for part in (text or "").split(","))):
        name, sep, spec = item.partition("=")
        low_text, colon, high_text = spec.partition(":")
        if name not in names or not sep or not colon:
            model = reference.model if reference is not None else DEFAULT_MODEL
            raise AppdgenError(f"--ranges {item!r}: expected NAME=LOW:HIGH with NAME a parameter of the {model} "
                               f"model: {', '.join(names)}")
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


def parameter_vector(calib: Calibration) -> np.ndarray:
    """A calibration's parameters in Calibration.param_names order (fx, fy, cx, cy in pixels, then coefficients)."""
    return np.array(list(calib.params().values()))


@dataclass(frozen=True, eq=False)
class ParameterBox:
    """The offsets a sampler may move a reference by: [low, high] per parameter (parameter units, names in
    Calibration.param_names order)."""

    reference: Calibration
    names: tuple[str, ...]
    base: np.ndarray  # the reference's parameters
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def around(cls, reference: Calibration, ranges: dict[str, Range]) -> ParameterBox:
        """The box the ranges span around a reference; AppdgenError when they name other parameters or are all
        empty."""
        names = reference.param_names
        odd = sorted(set(ranges) ^ set(names))
        if odd:
            raise AppdgenError(f"--ranges: {', '.join(odd)} not matching the {reference.model} model's "
                               f"parameters ({', '.join(names)})")
        values = parameter_vector(reference)
        bounds = [ranges[n].offsets(v) for n, v in zip(names, values, strict=True)]
        box = cls(reference, names, values, np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds]))
        if not (box.high - box.low > 0).any():
            raise AppdgenError("--ranges: every range is empty, so no perturbation is possible")
        return box

    def calibration(self, offsets: np.ndarray) -> Calibration:
        """The reference moved by parameter offsets (parameter units)."""
        return self.reference.replace(**dict(zip(self.names, (self.base + offsets).tolist(), strict=True)))

    def offsets(self, calib: Calibration) -> np.ndarray:
        """A calibration's offsets from the reference (parameter units)."""
        return parameter_vector(calib) - self.base

    def direction(self, rng: np.random.Generator) -> np.ndarray:
        """A uniform point of the box, pushed out along its ray to the box's boundary (parameter units)."""
        d = rng.uniform(self.low, self.high)
        reach = np.where(d > 0, d / np.where(self.high > 0, self.high, 1), d / np.where(self.low < 0, self.low, -1))
        return d / reach.max() if reach.max() > 0 else d

    def free(self) -> np.ndarray:
        """Indices of the parameters whose range is not empty."""
        return np.flatnonzero(self.high - self.low > 0)
