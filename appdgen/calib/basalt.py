"""Basalt ``calibration.json`` (cereal's ``value0``).

``intrinsics[i]`` with ``camera_type`` pinhole (radtan, all 0), kb4, ds, eucm or pinhole-radtan8 (rational) and
its named ``intrinsics`` (fx fy cx cy and the model's coefficients, Basalt's names being appdgen's),
``resolution[i]: [w, h]``. Cameras ``'cam0'``, ``'cam1'``, …: the index in ``intrinsics``, in file order.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, INTRINSICS
from appdgen.calib.fields import Found, Parts, allowed, as_mapping, k_matrix, need, number, read_size, short
from appdgen.errors import AppdgenError

#: Basalt ``camera_type`` → (appdgen model, how many of its coefficients ``intrinsics`` names; None: all).
_BASALT_MODELS: dict[str, tuple[str, int | None]] = {"pinhole": (DEFAULT_MODEL, 0), "kb4": ("kb4", None),
                                                     "ds": ("ds", None), "eucm": ("eucm", None),
                                                     "pinhole-radtan8": ("rational", 8)}


def recognise(doc: dict[Any, Any]) -> Found | None:
    """A Basalt calibration.json split into its cameras cam0, cam1, … in file order, or None."""
    calib = doc.get("value0")
    if not (isinstance(calib, dict) and "intrinsics" in calib):
        return None
    cameras = calib["intrinsics"]
    if not isinstance(cameras, list):
        raise AppdgenError(f"value0.intrinsics: expected a list of cameras, got {short(cameras)}")
    sizes = calib.get("resolution")
    if sizes is not None and (not isinstance(sizes, list) or len(sizes) != len(cameras)):
        raise AppdgenError(f"value0.resolution: expected a list of {len(cameras)} [width, height], "
                           f"got {short(sizes)}")
    return Found("Basalt calibration", {
        f"cam{i}": partial(_camera, camera, None if sizes is None else sizes[i], i)
        for i, camera in enumerate(cameras)})


def _camera(camera: Any, size: Any, index: int) -> Parts:
    """Size, K, model and coefficients of one Basalt camera: its camera_type and named intrinsics."""
    where = f"value0.intrinsics[{index}]"
    camera = as_mapping(where, camera)
    camera_type = need(camera, "camera_type", where)
    allowed(f"{where}.camera_type", camera_type, tuple(_BASALT_MODELS))
    model, count = _BASALT_MODELS[camera_type]
    values = as_mapping(f"{where}.intrinsics", need(camera, "intrinsics", where))
    names = INTRINSICS + lens.params(model)[:count]
    fx, fy, cx, cy, *coeffs = (number(f"{where}.intrinsics.{n}", need(values, n, f"{where}.intrinsics"))
                               for n in names)
    in_file = None if size is None else read_size(f"value0.resolution[{index}]", size)
    return in_file, k_matrix(fx, fy, cx, cy), model, np.array(coeffs)
