"""The options that shape every sample (parameter ranges, APPD cap, share of Θ*, field-of-view bound, remap
interpolation): one type for `appdgen build` and `python -m train fit --online`, and the sampler they set up."""
from __future__ import annotations

import functools
from dataclasses import dataclass

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.remap import DEFAULT_INTERP, INTERPOLATIONS
from appdgen.sampling.ranges import Range, default_ranges, parse_ranges
from appdgen.sampling.sampler import DEFAULT_APPD_MAX, Sampler

#: Fraction of samples that are exactly the reference calibration Θ*.
DEFAULT_ZERO_FRACTION = 0.01


@dataclass(frozen=True)
class SamplingOptions:
    """How samples are drawn and rendered: ranges (None: default_ranges of the reference), appd_max (% of the raw
    diagonal), zero_fraction, max_fov (degrees, None = unbounded) and the remap's interpolation."""

    ranges: tuple[tuple[str, Range], ...] | None = None  # sorted (name, Range) pairs: hashable, so cacheable
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = DEFAULT_ZERO_FRACTION
    max_fov: float | None = None
    interp: str = DEFAULT_INTERP

    def __post_init__(self) -> None:
        if self.interp not in INTERPOLATIONS:
            raise AppdgenError(f"--interp {self.interp!r}: expected one of {', '.join(INTERPOLATIONS)}")

    @classmethod
    def parse(cls, reference: Calibration, ranges: str | None = None, appd_max: float = DEFAULT_APPD_MAX,
              zero_fraction: float = DEFAULT_ZERO_FRACTION, max_fov: float | None = None,
              interp: str = DEFAULT_INTERP) -> "SamplingOptions":
        """The options as the command line gives them (--ranges text over the reference's defaults)."""
        return cls(tuple(sorted(parse_ranges(ranges, reference).items())), appd_max, zero_fraction, max_fov, interp)

    def range_map(self, reference: Calibration) -> dict[str, Range]:
        """The ranges by parameter name (the reference's defaults when none were given)."""
        return dict(self.ranges) if self.ranges is not None else default_ranges(reference)

    def build_fields(self, reference: Calibration) -> dict:
        """The keyword arguments of dataset.plan.BuildConfig these options stand for."""
        return {"ranges": self.range_map(reference), "appd_max": self.appd_max, "zero_fraction": self.zero_fraction,
                "max_fov": self.max_fov, "interp": self.interp}

    def describe(self, reference: Calibration) -> dict:
        """JSON-ready values, ranges as the CLI spells them (build.json's and a checkpoint's record)."""
        return {"appd_max": self.appd_max, "zero_fraction": self.zero_fraction, "interp": self.interp,
                "max_fov": self.max_fov,
                "ranges": {name: r.describe() for name, r in self.range_map(reference).items()}}

    def sampler(self, reference: Calibration, size: tuple[int, int]) -> Sampler:
        """The labelling sampler (full-grid labels and rectifications) at an output size, set up once per process."""
        ranges = self.ranges if self.ranges is not None else tuple(sorted(default_ranges(reference).items()))
        return _sampler(reference, ranges, self.appd_max, self.zero_fraction, tuple(size), self.max_fov)


@functools.lru_cache(maxsize=2)
def _sampler(reference: Calibration, ranges: tuple, appd_max: float, zero_fraction: float, size: tuple[int, int],
             max_fov: float | None) -> Sampler:
    """A worker's labelling sampler, kept for the next shard or batch of the same options (its set-up costs ~12 ms)."""
    return Sampler(reference, dict(ranges), appd_max, zero_fraction, size, max_fov=max_fov, labels=True)
