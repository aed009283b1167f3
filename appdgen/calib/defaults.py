"""The calibration used when none is given: KITTI raw 2011_09_26, shipped with the package."""
from __future__ import annotations

import importlib.resources
from pathlib import Path

from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import load

#: The published KITTI raw 2011_09_26 calib_cam_to_cam.txt (public KITTI data, www.cvlibs.net), as installed.
DEFAULT_CALIB_PATH: Path = Path(str(importlib.resources.files("appdgen") / "data"
                                     / "kitti_2011_09_26_calib_cam_to_cam.txt"))


def default_calibration(camera: str | int = "02") -> Calibration:
    """Θ of one KITTI 2011_09_26 camera ("00"…"03"; "02" is the left colour camera), unrectified, in pixels."""
    return load(DEFAULT_CALIB_PATH, camera)
