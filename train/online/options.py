"""What `fit --online` takes besides FitOptions, and the renderer it picks."""
from __future__ import annotations

import sys
from dataclasses import dataclass

import torch

from appdgen.calib.calibration import Calibration
from appdgen.geometry.remap import DEFAULT_INTERP
from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
from appdgen.sampling.sampler import DEFAULT_APPD_MAX
from train.errors import TrainError

#: --render choices: auto = device on CUDA (when its interpolation exists there), else cpu.
RENDERS = ("auto", "cpu", "device")


@dataclass(frozen=True)
class OnlineOptions:
    """What `fit --online` takes besides FitOptions: raw frames, calibration and the build's sampling options."""

    calib: str
    images: str
    camera: str | None = None
    split_by: str = "none"
    size: str | None = None  # WxH, default the raw size
    ranges: str | None = None
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = DEFAULT_ZERO_FRACTION
    max_fov: float | None = None
    interp: str = DEFAULT_INTERP
    render: str = "auto"
    val_shards: str | None = None  # validate on an offline build instead of fixed-seed online pairs
    topic: str | None = None  # which frames of a recording, as build's --topic/--every/--min-interval/--start/--end
    every: int = 1
    min_interval: float = 0.0
    start: float | None = None
    end: float | None = None

    def sampling(self, reference: Calibration) -> SamplingOptions:
        """The SamplingOptions these stand for (errors name the option)."""
        return SamplingOptions.parse(reference, self.ranges, self.appd_max, self.zero_fraction, self.max_fov,
                                     self.interp)


#: OnlineOptions that change the data: a resume must keep them (the renderer may change).
SAME_DATA = tuple(name for name in OnlineOptions.__dataclass_fields__ if name != "render")


def pick_render(render: str, interp: str, device: torch.device) -> str:
    """cpu or device: auto is device on CUDA unless grid_sample lacks the interpolation (lanczos4)."""
    from train.warp import DEVICE_INTERPOLATIONS

    if render not in RENDERS:
        raise TrainError(f"--render must be one of {', '.join(RENDERS)}, got {render!r}")
    if render == "auto":
        if device.type == "cuda" and interp not in DEVICE_INTERPOLATIONS:
            print(f"fit: --interp {interp} has no grid_sample kernel; rendering on the CPU (pass --interp cubic "
                  "for --render device)", file=sys.stderr)
        return "device" if device.type == "cuda" and interp in DEVICE_INTERPOLATIONS else "cpu"
    if render == "device" and interp not in DEVICE_INTERPOLATIONS:
        raise TrainError(f"--render device: --interp {interp} has no grid_sample kernel; use one of "
                         f"{', '.join(DEVICE_INTERPOLATIONS)}")
    return render
