"""Detect, read and write camera calibration files (parsing only: no geometry here).

``load`` recognises the format from the content, not the extension, and the lens model from the file:

* KITTI raw ``calib_cam_to_cam.txt``: ``S_xx`` (size), ``K_xx`` (3×3, row-major), ``D_xx`` (k1 k2 p1 p2 k3); the
  full published file or the reduced S/K/D-only layout, keys in any order, other keys ignored. Model radtan.
* OpenCV FileStorage YAML (OpenCV 4's ``%YAML:1.0`` or OpenCV 5's ``%YAML 1.2``, ``!!opencv-matrix``) and XML:
  ``camera_matrix``, ``distortion_coefficients`` (1×N or N×1), ``image_width``/``image_height`` (keys in any case).
  OpenCV's distortion vector (4, 5, 8, 12 or 14 numbers) becomes the smallest model that holds it exactly: radtan
  when every term past k3 is 0, else rational (k4 k5 k6, thin prism s1..s4); the tilted model (14 numbers with a
  non-zero τx or τy) is refused. ``distortion_model: fisheye`` or ``equidistant`` marks ``cv2.fisheye``'s model:
  kb4, exactly 4 numbers (k1..k4).
* ROS ``camera_info`` YAML: the same keys; ``distortion_model`` plumb_bob or rational_polynomial (the vector as
  above, as ROS hands it to OpenCV: a rational_polynomial file whose extra terms are all 0 is radtan, the same
  geometry under the model radtan builds already use), or equidistant (kb4).
* Kalibr camchain YAML (``camN:`` blocks; also OpenVINS's ``%YAML:1.0`` imu-camchain) and EuRoC ``sensor.yaml``:
  ``camera_model`` pinhole (``intrinsics: [fu, fv, pu, pv]``) with ``distortion_model`` radtan /
  radial-tangential (k1 k2 p1 p2; k3 = 0), equidistant (kb4: k1..k4) or none (radtan, all 0); ``camera_model`` ds
  (``intrinsics: [xi, alpha, fu, fv, pu, pv]``) or eucm (``[alpha, beta, fu, fv, pu, pv]``) with
  ``distortion_model: none``; ``resolution: [w, h]``. Kalibr's omni and fov are refused.
* Basalt ``calibration.json`` (cereal's ``value0``): ``intrinsics[i]`` with ``camera_type`` pinhole (radtan, all
  0), kb4, ds, eucm or pinhole-radtan8 (rational) and its named ``intrinsics`` (fx fy cx cy and the model's
  coefficients, Basalt's names being appdgen's), ``resolution[i]: [w, h]``.
* nuScenes ``calibrated_sensor.json``: a list of records; camera records have a 3×3 ``camera_intrinsic``, others an
  empty list. No distortion (radtan, all 0); images are ``NUSCENES_SIZE`` (1600×900) unless ``size`` says otherwise.
* appdgen JSON, as ``save`` writes it: version 2 has ``model`` and that model's parameter names; version 1 (no
  ``model``) is radtan.

Camera names (``list_cameras``) and ``camera=``:

* KITTI: the two-digit suffixes present (``'00'`` … ``'03'``).
* Kalibr camchain: the block names (``'cam0'``, ``'cam1'``, …).
* Basalt: ``'cam0'``, ``'cam1'``, …: the index in ``intrinsics``, in file order.
* nuScenes: ``'0'``, ``'1'``, …: the index among camera records, in file order.
* OpenCV, ROS, EuRoC and appdgen files hold one camera, named ``'0'``.

``camera`` matches a name exactly or by number, so ``2``, ``'2'``, ``'02'``, ``'image_02'`` and ``'cam2'`` all
pick KITTI ``'02'``, and ``'0'`` picks Kalibr ``'cam0'``. ``camera=None`` picks the only camera, and is an error
listing the names when there are several. The image size comes from the file; ``size=(width, height)`` is needed
only where the file has none (it must agree with the file where it has one).

``save`` writes appdgen JSON (every model, exact) or OpenCV FileStorage YAML (radtan: 5 numbers; rational: 8, or
12 with thin prism; kb4: 4 numbers and ``distortion_model: fisheye``). OpenCV has no ds or eucm, so those are
refused as YAML. A rational calibration whose extra terms are all 0 reads back from YAML as radtan (same maps).

Every failure raises ``AppdgenError`` with one line: ``<path>: <problem>``.
"""
from __future__ import annotations

import json
import os
import re
import reprlib
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, INTRINSICS, Calibration
from appdgen.util.atomic import atomic_write
from appdgen.errors import AppdgenError

__all__ = ["APPDGEN_FORMAT", "NUSCENES_SIZE", "list_cameras", "load", "save"]

#: Image size (width, height) in pixels of nuScenes camera images, whose calibration files do not state it.
NUSCENES_SIZE: tuple[int, int] = (1600, 900)
#: The ``format`` field of appdgen JSON calibration files.
APPDGEN_FORMAT = "appdgen-calibration"
#: Files larger than this (bytes) are refused unread; a full nuScenes calibrated_sensor.json is ~5 MB.
MAX_BYTES = 64 * 2**20

#: The appdgen JSON version ``save`` writes (2: with ``model``); version 1 (radtan, no ``model``) is still read.
APPDGEN_VERSION = 2

Size = tuple[int, int]
#: What a format reader yields for one camera: (image size in the file or None, 3×3 K in pixels, lens model name,
#: its coefficients in the model's order).
Parts = tuple[Size | None, np.ndarray, str, np.ndarray]
PathLike = str | os.PathLike[str]

_KITTI_KEY = re.compile(r"^[ \t]*[SKD]_([0-9]{2})[ \t]*:", re.MULTILINE)
_KALIBR_CAMERA = re.compile(r"cam[0-9]+")
_CAMERA_NUMBER = re.compile(r"(?:image|camera|cam)?[_ -]?0*([0-9]+)", re.IGNORECASE)
_FORMATS = "KITTI, OpenCV, ROS camera_info, Kalibr, EuRoC, Basalt, nuScenes or appdgen"
#: OpenCV/ROS ``distortion_model`` values → the model, None meaning "by the length of OpenCV's vector".
_OPENCV_MODELS: dict[str, str | None] = {"plumb_bob": None, "rational_polynomial": None, "equidistant": "kb4",
                                         "fisheye": "kb4"}
#: OpenCV's distortion vector: lengths it takes, and where the terms beyond radtan's five end for each model.
_OPENCV_LENGTHS = (4, 5, 8, 12, 14)
_TILT = 12
#: Kalibr ``camera_model`` → (appdgen model for distortion_model none, names read before fu fv pu pv).
_KALIBR_CAMERAS: dict[str, tuple[str, tuple[str, ...]]] = {"pinhole": (DEFAULT_MODEL, ()),
                                                           "ds": ("ds", ("xi", "alpha")),
                                                           "eucm": ("eucm", ("alpha", "beta"))}
#: Kalibr ``distortion_model`` of a pinhole camera → (appdgen model, number of distortion_coeffs).
_KALIBR_DISTORTIONS: dict[str, tuple[str, int]] = {"radtan": (DEFAULT_MODEL, 4),
                                                   "radial-tangential": (DEFAULT_MODEL, 4),
                                                   "equidistant": ("kb4", 4), "none": (DEFAULT_MODEL, 0)}
#: Basalt ``camera_type`` → (appdgen model, how many of its coefficients ``intrinsics`` names; None: all).
_BASALT_MODELS: dict[str, tuple[str, int | None]] = {"pinhole": (DEFAULT_MODEL, 0), "kb4": ("kb4", None),
                                                     "ds": ("ds", None), "eucm": ("eucm", None),
                                                     "pinhole-radtan8": ("rational", 8)}
#: Models OpenCV FileStorage YAML can hold, and the ``distortion_model`` written for them (None: none written).
_YAML_MODELS: dict[str, str | None] = {DEFAULT_MODEL: None, "rational": None, "kb4": "fisheye"}
_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 40
_REPR.maxlevel = 2


@dataclass(frozen=True)
class _Found:
    """A recognised file: its format's name, a reader per camera name, and the format's default image size."""

    kind: str
    cameras: dict[str, Callable[[], Parts]]
    default_size: Size | None = None


def load(path: PathLike, camera: str | int | None = None, size: Size | None = None) -> Calibration:
    """One camera's calibration (size and K in pixels, distortion unitless) from any supported file."""
    with _about(str(path)):
        found = _recognise(path)
        name = _select(list(found.cameras), camera)
        with _about(found.kind + (f" camera {name}" if len(found.cameras) > 1 else "")):
            in_file, K, model, coeffs = found.cameras[name]()
            return _calibration(_image_size(in_file, size, found.default_size), K, model, coeffs)


def list_cameras(path: PathLike) -> list[str]:
    """The camera names in a calibration file, in the order ``load(path, camera=…)`` accepts them."""
    with _about(str(path)):
        return list(_recognise(path).cameras)


def calibration_topic(path: PathLike, camera: str | int | None = None) -> str | None:
    """The ROS image topic a Kalibr camchain names for a camera (its ``rostopic``), None for files without one."""
    with _about(str(path)):
        found = _recognise(path)
        reader = found.cameras[_select(list(found.cameras), camera)]
    # Kalibr (and EuRoC sensor.yaml) readers hold their camera's block: the rostopic sits beside the intrinsics.
    block = reader.args[0] if isinstance(reader, partial) and reader.func is _kalibr_parts else None
    topic = block.get("rostopic") if isinstance(block, dict) else None
    return topic if isinstance(topic, str) and topic else None


def native_suffix(calib: Calibration) -> str:
    """The extension to save calib under: .yaml where OpenCV YAML holds its model (radtan, rational, kb4), else .json."""
    return ".yaml" if calib.model in _YAML_MODELS else ".json"


def save(calib: Calibration, path: PathLike) -> None:
    """Write atomically by extension: .yaml/.yml → OpenCV FileStorage YAML (radtan, rational, kb4), .json →
    appdgen JSON (every model); exact floats."""
    target = Path(path)
    writers = {".yaml": _opencv_yaml, ".yml": _opencv_yaml, ".json": _appdgen_json}
    with _about(str(path)):
        writer = writers.get(target.suffix.lower())
        if writer is None:
            raise AppdgenError(f"cannot write extension {target.suffix or '(none)'!r}; use .yaml, .yml or .json")
        _write_atomic(target, writer(calib))


# --- reading: text, syntax, format ---------------------------------------------------------------------------


def _recognise(path: PathLike) -> _Found:
    """Read the file and recognise its format and cameras."""
    return _detect(_read_text(Path(path)))


def _read_text(path: Path) -> str:
    """The file's UTF-8 text; missing, unreadable, oversized, binary and empty files are refused."""
    try:
        with path.open("rb") as stream:
            data = stream.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise AppdgenError("no such file") from None
    except IsADirectoryError:
        raise AppdgenError("is a directory, not a calibration file") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        raise AppdgenError(f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    if len(data) > MAX_BYTES:
        raise AppdgenError(f"larger than {MAX_BYTES >> 20} MiB: not a calibration file")
    if b"\0" in data:
        raise AppdgenError("binary data (NUL bytes), not a text calibration file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise AppdgenError(f"not UTF-8 text (byte {exc.start}): not a calibration file") from None
    if not text.strip():
        raise AppdgenError("empty file")
    return text


def _detect(text: str) -> _Found:
    """Recognise the format from the text and split it into cameras."""
    first = text.lstrip()[:1]
    if first == "<":
        return _classify(_parse_xml(text), "XML")
    if first in ("[", "{"):
        return _classify(_parse_json(text), "JSON")
    if _KITTI_KEY.search(text):
        return _kitti(text)
    return _classify(_parse_yaml(text), "YAML")


def _classify(doc: Any, syntax: str) -> _Found:
    """Recognise a parsed YAML, JSON or XML document by its shape and keys."""
    found = _nuscenes(doc) if isinstance(doc, list) else _by_keys(doc) if isinstance(doc, dict) else None
    if found is None:
        raise AppdgenError(f"unknown calibration format (read as {syntax}; expected {_FORMATS})")
    return found


def _nuscenes(records: list[Any]) -> _Found | None:
    """A nuScenes calibrated_sensor list; cameras are the records with a non-empty camera_intrinsic, by index."""
    if not any(isinstance(r, dict) and "camera_intrinsic" in r for r in records):
        return None
    cams = [r for r in records if isinstance(r, dict) and r.get("camera_intrinsic", []) != []]
    return _Found("nuScenes", {str(i): partial(_nuscenes_parts, r) for i, r in enumerate(cams)}, NUSCENES_SIZE)


def _by_keys(doc: dict[Any, Any]) -> _Found | None:
    """appdgen JSON, a Kalibr camchain, an EuRoC sensor.yaml or OpenCV/ROS, recognised by their keys."""
    if doc.get("format") == APPDGEN_FORMAT:
        return _Found("appdgen JSON", {"0": partial(_appdgen_parts, doc)})
    blocks = sorted((k for k in doc if isinstance(k, str) and _KALIBR_CAMERA.fullmatch(k)), key=lambda k: (len(k), k))
    if blocks:
        return _Found("Kalibr camchain", {k: partial(_kalibr_parts, doc[k]) for k in blocks})
    if isinstance(doc.get("value0"), dict) and "intrinsics" in doc["value0"]:
        return _basalt(doc["value0"])
    if "intrinsics" in doc:
        return _Found("EuRoC sensor.yaml", {"0": partial(_kalibr_parts, doc)})
    lowered = {k.lower(): v for k, v in doc.items() if isinstance(k, str)}
    if "camera_matrix" in lowered:
        return _Found("OpenCV/ROS", {"0": partial(_opencv_parts, lowered)})
    return None


class _OpenCVLoader(yaml.SafeLoader):
    """A SafeLoader that reads OpenCV's ``!!opencv-matrix`` (and other ``!!opencv-*``) nodes as mappings."""


_OpenCVLoader.add_multi_constructor(
    "tag:yaml.org,2002:opencv-", lambda loader, _suffix, node: loader.construct_mapping(node, deep=True)
)


def _parse_yaml(text: str) -> Any:
    """The YAML document, after dropping OpenCV 4's non-standard ``%YAML:1.0`` first line."""
    if text.startswith("%YAML:"):
        text = "\n" + text.partition("\n")[2]
    try:
        return yaml.load(text, Loader=_OpenCVLoader)  # noqa: S506 - a SafeLoader subclass
    except Exception as exc:  # PyYAML leaks KeyError ('!!bool x'), ValueError (bad dates), RecursionError…
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or f"{type(exc).__name__}: {exc}"
        raise AppdgenError(f"invalid YAML: {problem}{where}") from None


def _parse_json(text: str) -> Any:
    """The JSON document."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise AppdgenError(f"invalid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}") from None
    except (ValueError, RecursionError) as exc:  # over-long integers, too deep nesting
        raise AppdgenError(f"invalid JSON: {type(exc).__name__}: {exc}") from None


def _parse_xml(text: str) -> dict[str, Any]:
    """OpenCV FileStorage XML as {tag: text, or {child tag: text}}: the two levels a calibration uses."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise AppdgenError("XML with a DTD or entities is not supported")
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except (ET.ParseError, ValueError, LookupError) as exc:  # LookupError/ValueError: odd encoding declarations
        raise AppdgenError(f"invalid XML: {exc}") from None
    return {c.tag: {g.tag: _xml_text(g) for g in c} if len(c) else _xml_text(c) for c in root}


def _xml_text(element: ET.Element) -> str:
    """An element's text, stripped."""
    return (element.text or "").strip()


# --- reading: one camera per format --------------------------------------------------------------------------


def _kitti(text: str) -> _Found:
    """A KITTI calib_cam_to_cam.txt split into its cameras (the xx of S_xx/K_xx/D_xx keys)."""
    lines: dict[str, str] = {}
    for line in text.splitlines():
        key, colon, value = line.partition(":")
        if colon:
            if key.strip() in lines:
                raise AppdgenError(f"duplicate key {key.strip()}")
            lines[key.strip()] = value
    names = sorted({m.group(1) for m in _KITTI_KEY.finditer(text)})
    return _Found("KITTI", {n: partial(_kitti_parts, lines, n) for n in names})


def _kitti_parts(lines: dict[str, str], n: str) -> Parts:
    """Size, K and radtan coefficients of KITTI camera n from its S_n, K_n and D_n lines."""
    s = f"S_{n}"
    K = _numbers(f"K_{n}", _need(lines, f"K_{n}"), (9,)).reshape(3, 3)
    D = _numbers(f"D_{n}", _need(lines, f"D_{n}"), (4, 5))
    return (_size(s, lines[s]) if s in lines else None), K, DEFAULT_MODEL, D


def _opencv_parts(doc: dict[str, Any]) -> Parts:
    """Size, K, model and coefficients from OpenCV FileStorage or ROS camera_info keys (lower-cased)."""
    flavour = doc.get("distortion_model", "plumb_bob")
    _allowed("distortion_model", flavour, tuple(_OPENCV_MODELS))
    K = _cv_matrix("camera_matrix", doc["camera_matrix"])
    D = _cv_matrix("distortion_coefficients", _need(doc, "distortion_coefficients"))
    if 1 not in D.shape:
        raise AppdgenError(f"distortion_coefficients: expected 1xN or Nx1, got {D.shape[0]}x{D.shape[1]}")
    model = _OPENCV_MODELS[flavour]
    if model is None:
        model, coeffs = _opencv_vector(D.ravel())
    else:
        coeffs = _counted(f"distortion_coefficients ({flavour}: {', '.join(lens.params(model))})", D.ravel(),
                          len(lens.params(model)))
    return _optional_size(doc, "image_width", "image_height"), K, model, coeffs


def _opencv_vector(D: np.ndarray) -> tuple[str, np.ndarray]:
    """OpenCV's distortion vector → the smallest model holding it exactly: radtan, else rational; tilt refused."""
    D = _counted("distortion_coefficients", D, *_OPENCV_LENGTHS)
    if np.any(D[_TILT:] != 0):
        raise AppdgenError("OpenCV's tilted model (14 distortion coefficients with a non-zero tau_x or tau_y) "
                           "is not supported")
    radtan = len(lens.params(DEFAULT_MODEL))
    if np.all(D[radtan:] == 0):
        return DEFAULT_MODEL, D[:radtan]
    return "rational", D[:_TILT]


def _kalibr_parts(camera: Any) -> Parts:
    """Size, K, model and coefficients from a Kalibr camchain camera block or an EuRoC sensor.yaml."""
    cam = _mapping("camera", camera)
    camera_model, distortion = _need(cam, "camera_model"), _need(cam, "distortion_model")
    _allowed("camera_model", camera_model, tuple(_KALIBR_CAMERAS))
    model, leading = _KALIBR_CAMERAS[camera_model]
    if camera_model == "pinhole":
        _allowed("distortion_model", distortion, tuple(_KALIBR_DISTORTIONS))
        model, count = _KALIBR_DISTORTIONS[distortion]
    elif distortion != "none":
        raise AppdgenError(f"camera_model {camera_model} with distortion_model {_REPR.repr(distortion)} is not "
                           "supported; expected none")
    else:
        count = 0
    names = (*leading, "fu", "fv", "pu", "pv")
    intrinsics = _need(cam, "intrinsics")
    if isinstance(intrinsics, list) and len(intrinsics) != len(names):
        raise AppdgenError(f"intrinsics: camera_model {camera_model} expects {len(names)} numbers "
                           f"[{', '.join(names)}], got {len(intrinsics)}")
    values = dict(zip(names, _numbers("intrinsics", intrinsics, (len(names),))))
    key = "distortion_coeffs" if "distortion_coeffs" in cam else "distortion_coefficients"
    distortion_coeffs = _numbers(f"{key} ({distortion})", _need(cam, key) if count else cam.get(key, []), (count,))
    coeffs = np.array([values[name] for name in leading]) if leading else distortion_coeffs
    K = _k_matrix(values["fu"], values["fv"], values["pu"], values["pv"])
    return _optional_size(cam, "resolution"), K, model, coeffs


def _basalt(calib: dict[str, Any]) -> _Found:
    """A Basalt calibration.json (cereal's value0) split into its cameras cam0, cam1, … in file order."""
    cameras = calib["intrinsics"]
    if not isinstance(cameras, list):
        raise AppdgenError(f"value0.intrinsics: expected a list of cameras, got {_REPR.repr(cameras)}")
    sizes = calib.get("resolution")
    if sizes is not None and (not isinstance(sizes, list) or len(sizes) != len(cameras)):
        raise AppdgenError(f"value0.resolution: expected a list of {len(cameras)} [width, height], "
                           f"got {_REPR.repr(sizes)}")
    return _Found("Basalt calibration", {
        f"cam{i}": partial(_basalt_parts, camera, None if sizes is None else sizes[i], i)
        for i, camera in enumerate(cameras)})


def _basalt_parts(camera: Any, size: Any, index: int) -> Parts:
    """Size, K, model and coefficients of one Basalt camera: its camera_type and named intrinsics."""
    where = f"value0.intrinsics[{index}]"
    camera = _mapping(where, camera)
    camera_type = _need(camera, "camera_type", where)
    _allowed(f"{where}.camera_type", camera_type, tuple(_BASALT_MODELS))
    model, count = _BASALT_MODELS[camera_type]
    values = _mapping(f"{where}.intrinsics", _need(camera, "intrinsics", where))
    names = INTRINSICS + lens.params(model)[:count]
    fx, fy, cx, cy, *coeffs = (_number(f"{where}.intrinsics.{n}", _need(values, n, f"{where}.intrinsics"))
                               for n in names)
    in_file = None if size is None else _size(f"value0.resolution[{index}]", size)
    return in_file, _k_matrix(fx, fy, cx, cy), model, np.array(coeffs)


def _nuscenes_parts(record: dict[str, Any]) -> Parts:
    """K from a nuScenes calibrated_sensor camera record (no size, no distortion)."""
    rows = record["camera_intrinsic"]
    if not isinstance(rows, list) or len(rows) != 3:
        raise AppdgenError(f"camera_intrinsic: expected a 3x3 list of lists, got {_REPR.repr(rows)}")
    K = np.array([_numbers(f"camera_intrinsic[{i}]", row, (3,)) for i, row in enumerate(rows)])
    return None, K, DEFAULT_MODEL, np.zeros(0)


def _appdgen_parts(doc: dict[str, Any]) -> Parts:
    """Size, K, model and coefficients from appdgen JSON (version 2; version 1 is radtan without ``model``)."""
    version = doc.get("version")
    if version not in (1, APPDGEN_VERSION) or isinstance(version, bool):
        raise AppdgenError(f"unsupported {APPDGEN_FORMAT} version {_REPR.repr(version)}; "
                           f"expected 1 or {APPDGEN_VERSION}")
    model = DEFAULT_MODEL if version == 1 else _need(doc, "model")
    if not isinstance(model, str):
        raise AppdgenError(f"model: expected a lens model name, got {_REPR.repr(model)}")
    fx, fy, cx, cy, *coeffs = (_number(name, _need(doc, name)) for name in (*INTRINSICS, *lens.params(model)))
    return _optional_size(doc, "width", "height"), _k_matrix(fx, fy, cx, cy), model, np.array(coeffs)


# --- reading: shared value helpers ---------------------------------------------------------------------------


def _need(mapping: dict[str, Any], key: str, where: str = "") -> Any:
    """mapping[key], or an error naming the missing key."""
    if key not in mapping:
        raise AppdgenError(f"missing key {where + '.' if where else ''}{key}")
    return mapping[key]


def _mapping(what: str, value: Any) -> dict[str, Any]:
    """value if it is a mapping."""
    if not isinstance(value, dict):
        raise AppdgenError(f"{what}: expected a mapping, got {_REPR.repr(value)}")
    return value


def _allowed(what: str, value: Any, allowed: tuple[str, ...]) -> None:
    """Refuse a model name outside `allowed`."""
    if value not in allowed:
        raise AppdgenError(f"{what} {_REPR.repr(value)} is not supported; supported: {', '.join(allowed)}")


def _number(what: str, value: Any) -> float:
    """A finite float from a number or numeric string (YAML 1.1 reads '1e-05' as a string); bools refused."""
    try:
        if isinstance(value, (int, float, str)) and not isinstance(value, bool):
            number = float(value)
            if np.isfinite(number):
                return number
    except (ValueError, OverflowError):
        pass
    raise AppdgenError(f"{what}: expected a finite number, got {_REPR.repr(value)}")


def _numbers(what: str, value: Any, counts: tuple[int, ...]) -> np.ndarray:
    """Floats from a list or a whitespace-separated string, whose length must be one of `counts`."""
    items = value.split() if isinstance(value, str) else value
    if not isinstance(items, list):
        raise AppdgenError(f"{what}: expected a list of numbers, got {_REPR.repr(value)}")
    if len(items) not in counts:
        raise AppdgenError(f"{what}: expected {' or '.join(map(str, counts))} numbers, got {len(items)}")
    return np.array([_number(f"{what}[{i}]", item) for i, item in enumerate(items)], dtype=float)


def _counted(what: str, values: np.ndarray, *counts: int) -> np.ndarray:
    """values if their number is one of `counts`."""
    if values.size not in counts:
        raise AppdgenError(f"{what}: expected {' or '.join(map(str, counts))} numbers, got {values.size}")
    return values


def _size(what: str, value: Any) -> Size:
    """(width, height) in whole pixels from a 2-number list or string."""
    width, height = _numbers(what, value, (2,))
    if not (width.is_integer() and height.is_integer()):
        raise AppdgenError(f"{what}: image size must be whole pixels, got {width:g}x{height:g}")
    return int(width), int(height)


def _optional_size(mapping: dict[str, Any], *keys: str) -> Size | None:
    """The image size (pixels) under one [w, h] key or two keys (w, h); None if they are all absent."""
    if not any(k in mapping for k in keys):
        return None
    values = [_need(mapping, k) for k in keys]
    return _size("/".join(keys), values[0] if len(keys) == 1 else values)


def _cv_matrix(what: str, node: Any) -> np.ndarray:
    """A rows×cols array from an OpenCV/ROS matrix node {rows, cols, data}."""
    node = _mapping(what, node)
    rows, cols = (_number(f"{what}.{k}", _need(node, k, what)) for k in ("rows", "cols"))
    if not (rows.is_integer() and cols.is_integer() and rows >= 1 and cols >= 1):
        raise AppdgenError(f"{what}: rows and cols must be positive whole numbers, got {rows:g} and {cols:g}")
    return _numbers(f"{what}.data", _need(node, "data", what), (int(rows) * int(cols),)).reshape(int(rows), int(cols))


def _k_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3×3 camera matrix (pixels) from focal lengths and principal point."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _calibration(size: Size, K: np.ndarray, model: str, coeffs: np.ndarray) -> Calibration:
    """The validated Calibration from image size (pixels), 3×3 K (pixels), lens model and its coefficients."""
    if K.shape != (3, 3):
        raise AppdgenError(f"camera matrix: expected 3x3, got {'x'.join(map(str, K.shape))}")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise AppdgenError("camera matrix: expected the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (transposed?)")
    try:
        return Calibration.from_arrays(size[0], size[1], K, coeffs, model=model)
    except AppdgenError as exc:
        raise AppdgenError(str(exc).removeprefix("calibration: ")) from None


def _image_size(in_file: Size | None, given: Any, default: Size | None) -> Size:
    """The file's image size (pixels), else `given`, else the format's default; a disagreement is an error."""
    if given is not None:
        given = _size("size", list(given) if isinstance(given, (tuple, np.ndarray)) else given)
        if in_file is not None and given != in_file:
            raise AppdgenError(f"size {given[0]}x{given[1]} given, but the file says {in_file[0]}x{in_file[1]}")
    chosen = in_file or given or default
    if chosen is None:
        raise AppdgenError("no image size in the file; pass size=(width, height)")
    return chosen


def _select(names: list[str], camera: str | int | None) -> str:
    """The camera name that `camera` picks (exactly or by number); None picks the only camera."""
    if not names:
        raise AppdgenError("no camera in the file")
    if camera is None:
        if len(names) == 1:
            return names[0]
        raise AppdgenError(f"{len(names)} cameras; choose one with --camera (camera= in Python); available: {_listing(names)}")
    wanted = str(camera).strip()
    number = _camera_number(wanted)
    matches = [n for n in names if n == wanted] or [n for n in names if number and _camera_number(n) == number]
    if len(matches) != 1:
        raise AppdgenError(f"camera {wanted!r} not found; available: {_listing(names)}")
    return matches[0]


def _camera_number(name: str) -> str | None:
    """The number in a camera name without leading zeros ('image_02' → '2'), or None."""
    match = _CAMERA_NUMBER.fullmatch(name)
    return match.group(1) if match else None


def _listing(names: list[str], most: int = 12) -> str:
    """Camera names for a message, cut short after `most`."""
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown}, … ({len(names)} in all)"


@contextmanager
def _about(subject: str) -> Iterator[None]:
    """Re-raise an AppdgenError from inside as one line prefixed with ``subject: ``."""
    try:
        yield
    except AppdgenError as exc:
        raise AppdgenError(" ".join(f"{subject}: {exc}".splitlines())) from None


# --- writing ---------------------------------------------------------------------------------------------------


def _opencv_yaml(calib: Calibration) -> str:
    """OpenCV FileStorage YAML (``%YAML:1.0``, as OpenCV 4 writes it) with shortest exact float reprs."""
    if calib.model not in _YAML_MODELS:
        raise AppdgenError(f"OpenCV YAML cannot hold lens model {calib.model!r} (OpenCV has no such model); "
                           "save it as .json")
    flavour = _YAML_MODELS[calib.model]
    head = f"image_width: {calib.width}\nimage_height: {calib.height}\n"
    head += f"distortion_model: {flavour}\n" if flavour else ""
    D = calib.D
    if calib.model == "rational" and np.all(D[8:] == 0):
        D = D[:8]  # OpenCV's 8-coefficient rational vector; 12 only when the thin-prism terms are used
    return "%YAML:1.0\n---\n" + head + _cv_matrix_text("camera_matrix", calib.K) + _cv_matrix_text(
        "distortion_coefficients", D.reshape(1, -1)
    )


def _cv_matrix_text(name: str, matrix: np.ndarray) -> str:
    """One ``!!opencv-matrix`` node of doubles."""
    data = ", ".join(repr(float(v)) for v in matrix.ravel())
    rows, cols = matrix.shape
    return f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"


def _appdgen_json(calib: Calibration) -> str:
    """appdgen JSON (version 2): format tag, version, model, size and the model's parameters, exact float reprs."""
    fields = calib.to_dict()
    header = {"format": APPDGEN_FORMAT, "version": APPDGEN_VERSION, "model": fields.pop("model")}
    return json.dumps({**header, **fields}, indent=2) + "\n"


def _write_atomic(target: Path, text: str) -> None:
    """Write text atomically, turning OS failures into AppdgenError."""
    try:
        atomic_write(target, text.encode("utf-8"))
    except OSError as exc:
        raise AppdgenError(f"cannot write: {exc.strerror or exc}") from None
