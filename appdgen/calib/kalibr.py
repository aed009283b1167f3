"""Kalibr camchain YAML (``camN:`` blocks; also OpenVINS's ``%YAML:1.0`` imu-camchain) and EuRoC ``sensor.yaml``.

``camera_model`` pinhole (``intrinsics: [fu, fv, pu, pv]``) with ``distortion_model`` radtan / radial-tangential
(k1 k2 p1 p2; k3 = 0), equidistant (kb4: k1..k4) or none (radtan, all 0); ``camera_model`` ds (``intrinsics:
[xi, alpha, fu, fv, pu, pv]``) or eucm (``[alpha, beta, fu, fv, pu, pv]``) with ``distortion_model: none``;
``resolution: [w, h]``. Kalibr's omni and fov are refused. Cameras: the camchain's block names (``'cam0'``,
``'cam1'``, …); a sensor.yaml holds one, named ``'0'``.
"""
from __future__ import annotations

import re
from functools import partial
from typing import Any

import numpy as np

from appdgen.calib.calibration import DEFAULT_MODEL
from appdgen.calib.fields import Found, Parts, allowed, as_mapping, k_matrix, need, numbers, optional_size, short
from appdgen.errors import AppdgenError

_KALIBR_CAMERA = re.compile(r"cam[0-9]+")
#: Kalibr ``camera_model`` → (appdgen model for distortion_model none, names read before fu fv pu pv).
_KALIBR_CAMERAS: dict[str, tuple[str, tuple[str, ...]]] = {"pinhole": (DEFAULT_MODEL, ()),
                                                           "ds": ("ds", ("xi", "alpha")),
                                                           "eucm": ("eucm", ("alpha", "beta"))}
#: Kalibr ``distortion_model`` of a pinhole camera → (appdgen model, number of distortion_coeffs).
_KALIBR_DISTORTIONS: dict[str, tuple[str, int]] = {"radtan": (DEFAULT_MODEL, 4),
                                                   "radial-tangential": (DEFAULT_MODEL, 4),
                                                   "equidistant": ("kb4", 4), "none": (DEFAULT_MODEL, 0)}


def recognise_camchain(doc: dict[Any, Any]) -> Found | None:
    """A Kalibr camchain (``camN`` blocks, in number order), or None."""
    blocks = sorted((k for k in doc if isinstance(k, str) and _KALIBR_CAMERA.fullmatch(k)), key=lambda k: (len(k), k))
    if blocks:
        return Found("Kalibr camchain", {k: partial(_camera, doc[k]) for k in blocks},
                     topics={k: t for k in blocks if (t := _topic(doc[k]))})
    return None


def recognise_sensor(doc: dict[Any, Any]) -> Found | None:
    """An EuRoC sensor.yaml (one Kalibr camera block at the top level), or None."""
    if "intrinsics" in doc:
        return Found("EuRoC sensor.yaml", {"0": partial(_camera, doc)}, topics={"0": t} if (t := _topic(doc)) else {})
    return None


def _topic(camera: Any) -> str | None:
    """A camera block's ``rostopic`` (the bag topic Kalibr read its images from), None where it names none."""
    topic = camera.get("rostopic") if isinstance(camera, dict) else None
    return topic if isinstance(topic, str) and topic else None


def _camera(camera: Any) -> Parts:
    """Size, K, model and coefficients from a Kalibr camchain camera block or an EuRoC sensor.yaml."""
    cam = as_mapping("camera", camera)
    camera_model, distortion = need(cam, "camera_model"), need(cam, "distortion_model")
    allowed("camera_model", camera_model, tuple(_KALIBR_CAMERAS))
    model, leading = _KALIBR_CAMERAS[camera_model]
    if camera_model == "pinhole":
        allowed("distortion_model", distortion, tuple(_KALIBR_DISTORTIONS))
        model, count = _KALIBR_DISTORTIONS[distortion]
    elif distortion != "none":
        raise AppdgenError(f"camera_model {camera_model} with distortion_model {short(distortion)} is not "
                           "supported; expected none")
    else:
        count = 0
    names = (*leading, "fu", "fv", "pu", "pv")
    intrinsics = need(cam, "intrinsics")
    if isinstance(intrinsics, list) and len(intrinsics) != len(names):
        raise AppdgenError(f"intrinsics: camera_model {camera_model} expects {len(names)} numbers "
                           f"[{', '.join(names)}], got {len(intrinsics)}")
    values = dict(zip(names, numbers("intrinsics", intrinsics, (len(names),)), strict=True))
    key = "distortion_coeffs" if "distortion_coeffs" in cam else "distortion_coefficients"
    distortion_coeffs = numbers(f"{key} ({distortion})", need(cam, key) if count else cam.get(key, []), (count,))
    coeffs = np.array([values[name] for name in leading]) if leading else distortion_coeffs
    K = k_matrix(values["fu"], values["fv"], values["pu"], values["pv"])
    return optional_size(cam, "resolution"), K, model, coeffs
