"""The calibration used when none is given: KITTI raw 2011_09_26, shipped with the package."""
from __future__ import annotations

import importlib.resources
from pathlib import Path

import numpy as np

from appdgen.calibration import Calibration
from appdgen.errors import AppdgenError

#: The published KITTI raw 2011_09_26 calib_cam_to_cam.txt (public KITTI data), as installed.
DEFAULT_CALIB_PATH: Path = Path(str(importlib.resources.files("appdgen") / "data" / "kitti_2011_09_26_calib_cam_to_cam.txt"))


def default_calibration(camera: str | int = "02") -> Calibration:
    """Θ of one KITTI 2011_09_26 camera ("00"…"03"; "02" is the left colour camera), unrectified, in pixels."""
    return _read_kitti_camera(DEFAULT_CALIB_PATH, f"{camera:02d}" if isinstance(camera, int) else camera)


def _read_kitti_camera(path: Path, camera: str) -> Calibration:
    """Size S_xx, matrix K_xx and distortion D_xx of one camera from a KITTI calib_cam_to_cam.txt."""
    fields: dict[str, str] = {}
    for line in Path(path).read_text().splitlines():
        key, sep, value = line.partition(":")
        if sep:
            fields[key.strip()] = value
    try:
        size, K, D = (np.array(fields[f"{key}_{camera}"].split(), dtype=float) for key in ("S", "K", "D"))
    except KeyError as missing:
        raise AppdgenError(f"{path}: no entry {missing.args[0]} (camera {camera!r})") from None
    except ValueError as err:
        raise AppdgenError(f"{path}: camera {camera!r}: {err}") from None
    if size.size != 2 or K.size != 9:
        raise AppdgenError(f"{path}: camera {camera!r}: expected 2 numbers in S and 9 in K")
    return Calibration.from_arrays(int(size[0]), int(size[1]), K.reshape(3, 3), D)
