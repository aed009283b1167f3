"""nuScenes ``calibrated_sensor.json``: a list of records; camera records have a 3×3 ``camera_intrinsic``, others
an empty list. No distortion (radtan, all 0); images are NUSCENES_SIZE unless ``size`` says otherwise. Cameras
``'0'``, ``'1'``, …: the index among camera records, in file order."""
from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from appdgen.calib.calibration import DEFAULT_MODEL
from appdgen.calib.fields import Found, Parts, numbers, short
from appdgen.errors import AppdgenError

#: Image size (width, height) in pixels of nuScenes camera images, whose calibration files do not state it.
NUSCENES_SIZE: tuple[int, int] = (1600, 900)


def recognise(records: list[Any]) -> Found | None:
    """A nuScenes calibrated_sensor list; cameras are the records with a non-empty camera_intrinsic, by index."""
    if not any(isinstance(r, dict) and "camera_intrinsic" in r for r in records):
        return None
    cams = [r for r in records if isinstance(r, dict) and r.get("camera_intrinsic", []) != []]
    return Found("nuScenes", {str(i): partial(_camera, r) for i, r in enumerate(cams)}, NUSCENES_SIZE)


def _camera(record: dict[str, Any]) -> Parts:
    """K from a nuScenes calibrated_sensor camera record (no size, no distortion)."""
    rows = record["camera_intrinsic"]
    if not isinstance(rows, list) or len(rows) != 3:
        raise AppdgenError(f"camera_intrinsic: expected a 3x3 list of lists, got {short(rows)}")
    K = np.array([numbers(f"camera_intrinsic[{i}]", row, (3,)) for i, row in enumerate(rows)])
    return None, K, DEFAULT_MODEL, np.zeros(0)
