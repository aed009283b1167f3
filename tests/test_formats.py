"""appdgen.calib.formats: real files, small fixtures, malformed files, writers, and fuzzing that only AppdgenError
escapes."""
from __future__ import annotations

import csv
import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from appdgen import AppdgenError, Calibration, lens
from appdgen.calib import formats
from appdgen.calib.formats import list_cameras, load, save
from appdgen.calib.nuscenes import NUSCENES_SIZE

FIXTURES = Path(__file__).parent / "data" / "calib"
VALID = sorted(p for p in FIXTURES.iterdir() if not p.name.startswith("bad_"))
FUZZ = settings(max_examples=40, deadline=None, database=None)


def _shared_data() -> Path | None:
    """The shared real-data folder: $APPDGEN_SHARED_DATA, else ../shared/data beside the repository."""
    env = os.environ.get("APPDGEN_SHARED_DATA")
    root = Path(env) if env else Path(__file__).parents[1] / ".." / "shared" / "data"
    return root if root.is_dir() else None


@pytest.fixture(scope="module")
def shared() -> Path:
    root = _shared_data()
    if root is None:
        pytest.skip("shared real-data folder absent (set APPDGEN_SHARED_DATA)")
    return root


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("formats")


def _cv2_read(path: Path, k: str, d: str, w: str, h: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Size, K and D read by cv2.FileStorage: the independent check of OpenCV files."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        return int(fs.getNode(w).real()), int(fs.getNode(h).real()), fs.getNode(k).mat(), fs.getNode(d).mat()
    finally:
        fs.release()


def _same(calib: Calibration, width: int, height: int, K, D) -> None:
    """Assert calib equals size, K and D (D padded with zeros to 5) exactly."""
    assert calib.size == (width, height)
    np.testing.assert_array_equal(calib.K, np.asarray(K, dtype=float))
    d = np.ravel(np.asarray(D, dtype=float))
    np.testing.assert_array_equal(calib.D, np.concatenate([d, np.zeros(5)])[:5])


# --- real files --------------------------------------------------------------------------------------------------


def test_kitti_every_day_and_camera_matches_values_csv(shared: Path) -> None:
    with open(shared / "kitti" / "values.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert len(rows) == 14
    for row in rows:
        path = shared / "kitti" / row["day"] / "calib_cam_to_cam.txt"
        values = {k: v for k, v in row.items() if k not in ("day", "camera")}
        expected = {k: (int(v) if k in ("width", "height") else float(v)) for k, v in values.items()}
        assert load(path, camera=row["camera"]).to_dict() == {**expected, "model": "radtan"}, row
    for day in {row["day"] for row in rows}:
        cameras = sorted(row["camera"] for row in rows if row["day"] == day)
        assert list_cameras(shared / "kitti" / day / "calib_cam_to_cam.txt") == cameras


@pytest.mark.parametrize("name", ["opencv_kitti_2011_09_26_cam02.yaml", "opencv_kitti_2011_09_26_cam02.xml"])
def test_real_opencv5_files_agree_with_cv2_and_kitti(shared: Path, name: str) -> None:
    path = shared / "formats" / name
    calib = load(path)
    _same(calib, *_cv2_read(path, "camera_matrix", "distortion_coefficients", "image_width", "image_height"))
    assert calib == load(shared / "kitti" / "2011_09_26" / "calib_cam_to_cam.txt", camera="02")


def test_real_ros_camera_info(shared: Path) -> None:
    path = shared / "formats" / "ros_camera_info_kodak.yaml"
    doc = yaml.safe_load(path.read_text())
    calib = load(path)
    _same(calib, 1440, 1440, np.reshape(doc["camera_matrix"]["data"], (3, 3)), doc["distortion_coefficients"]["data"])


@pytest.mark.parametrize("name", ["kalibr_camchain_euroc.yaml", "camchain.yaml", "kalibr_imucam_chain.yaml"])
def test_real_kalibr_camchains(shared: Path, name: str) -> None:
    path = shared / "formats" / name
    doc = yaml.safe_load(path.read_text().removeprefix("%YAML:1.0"))
    assert list_cameras(path) == sorted(doc)
    for cam, block in doc.items():
        (fu, fv, pu, pv), (w, h) = block["intrinsics"], block["resolution"]
        _same(load(path, camera=cam), w, h, [[fu, 0, pu], [0, fv, pv], [0, 0, 1]], block["distortion_coeffs"])


def test_real_euroc_files_agree(shared: Path) -> None:
    sensor = load(shared / "formats" / "euroc_cam0_sensor.yaml")
    assert sensor.to_dict() == {"width": 752, "height": 480, "model": "radtan", "fx": 458.654, "fy": 457.296,
                                "cx": 367.215,
                                "cy": 248.375, "k1": -0.28340811, "k2": 0.07395907, "p1": 0.00019359,
                                "p2": 1.76187114e-05, "k3": 0.0}
    assert sensor == load(shared / "formats" / "kalibr_imucam_chain.yaml", camera="cam0")
    for cam in ("0", "1"):
        assert load(shared / "formats" / "kalibr_imucam_chain.yaml", cam) == load(
            shared / "formats" / "kalibr_camchain_euroc.yaml", cam)


def test_real_tumvi_kalibr_equidistant_is_kb4(shared: Path) -> None:
    path = shared / "formats" / "kalibr_tumvi_pinhole_equi.yaml"
    doc = yaml.safe_load(path.read_text())
    assert list_cameras(path) == ["cam0", "cam1"]
    for cam, block in doc.items():
        (fx, fy, cx, cy), (w, h) = block["intrinsics"], block["resolution"]
        assert load(path, cam) == Calibration(w, h, fx, fy, cx, cy, *block["distortion_coeffs"], model="kb4")
    assert load(path, "cam0").to_dict() == {
        "width": 512, "height": 512, "model": "kb4", "fx": 190.97847715128717, "fy": 190.9733070521226,
        "cx": 254.93170605935475, "cy": 256.8974428996504, "k1": 0.0034823894022493434, "k2": 0.0007150348452162257,
        "k3": -0.0020532361418706202, "k4": 0.00020293673591811182}


@pytest.mark.parametrize(("name", "model"), [("basalt_t265_kb4_calib.json", "kb4"),
                                             ("basalt_euroc_eucm_calib.json", "eucm")])
def test_real_basalt_files(shared: Path, name: str, model: str) -> None:
    path = shared / "formats" / name
    doc = json.loads(path.read_text())["value0"]
    assert list_cameras(path) == ["cam0", "cam1"]
    for i, (camera, (w, h)) in enumerate(zip(doc["intrinsics"], doc["resolution"], strict=True)):
        assert camera["camera_type"] == model
        calib = load(path, camera=i)
        assert calib.model == model and calib.size == (w, h)
        assert calib.params() == camera["intrinsics"]  # Basalt's names are appdgen's
    assert load(shared / "formats" / "basalt_t265_kb4_calib.json", "cam1").k4 == 0.009643678532407407
    assert load(shared / "formats" / "basalt_euroc_eucm_calib.json", "cam0").beta == 1.127468196965374


def test_real_ros_rational_polynomial_is_rational(shared: Path) -> None:
    path = shared / "formats" / "ros_camera_info_rational_2880x1860.yaml"
    calib = load(path)
    assert calib.model == "rational" and calib.size == (2880, 1860)
    np.testing.assert_array_equal(calib.K, [[1495.316895, 0, 1424.459106], [0, 1494.778564, 943.463684], [0, 0, 1]])
    assert calib.coeffs == (0.929988205433, 0.165922805667, -0.000024369263, -0.000013859207, 0.002885974478,
                            1.331432461739, 0.435830116272, 0.027607271448, 0.0, 0.0, 0.0, 0.0)
    _same_as_ros_yaml(calib, path)


def test_real_kodak_plumb_bob_stays_radtan(shared: Path) -> None:
    calib = load(shared / "formats" / "ros_camera_info_kodak.yaml")
    assert calib.model == "radtan" and calib.k1 == -0.1710342568253523 and calib.k3 == 0.0


def test_real_nuscenes(shared: Path) -> None:
    path = shared / "formats" / "nuscenes_calibrated_sensor.json"
    intrinsic = json.loads(path.read_text())[0]["camera_intrinsic"]
    assert list_cameras(path) == ["0"]
    _same(load(path), *NUSCENES_SIZE, intrinsic, [])
    assert load(path, size=(800, 450)).size == (800, 450)


# --- fixtures ----------------------------------------------------------------------------------------------------

EXPECTED = {  # file, camera → (width, height, fx, fy, cx, cy, k1, k2, p1, p2, k3)
    ("appdgen.json", None): (1280, 720, 1000.0000000000001, 999.5, 640.125, 359.875, -0.31, 0.12, 0.0015, -0.00025,
                             -0.0625),
    ("euroc_sensor.yaml", None): (752, 480, 450.5, 451.5, 370.25, 240.125, -0.28, 0.07, 0.0002, 1.5e-05, 0),
    ("kalibr.yaml", "cam0"): (640, 480, 400.5, 401.5, 320.25, 240.75, -0.25, 0.07, 1e-4, -2.5e-05, 0),
    ("kalibr.yaml", "cam1"): (640, 480, 402.0, 403.0, 321.0, 241.0, -0.26, 0.08, -0.0001, 3e-05, 0),
    ("kitti_reduced.txt", "02"): (1392, 512, 961, 957, 694, 236, -0.369, 0.198, 0.000599, 0.000897, -0.0682),
    ("kitti_reduced.txt", "03"): (1392, 512, 905, 902, 695, 235, -0.364, 0.185, -0.000387, 0.000128, -0.0596),
    ("nuscenes.json", "0"): (1600, 900, 1260.5, 1260.5, 800.25, 450.75, 0, 0, 0, 0, 0),
    ("nuscenes.json", "1"): (1600, 900, 800.0, 800.0, 801.0, 451.0, 0, 0, 0, 0, 0),
    ("opencv.xml", None): (800, 600, 500.25, 501.125, 399.5, 299.5, -0.125, 0.03125, 1e-05, -2e-05, 0),
    ("opencv4.yml", None): (640, 480, 600.12345678901234, 600.12345678901234, 319.5, 239.5, -0.4, 0.5, 0, 0, -0.575),
    ("ros_rational.yaml", None): (1024, 768, 700.5, 701.25, 511.5, 383.5, -0.2, 0.05, 0.001, -0.002, 0.01),
}


MODEL_EXPECTED = {  # file, camera → (width, height, fx, fy, cx, cy, model, coefficients), written by hand
    ("kalibr_models.yaml", "cam0"): (640, 480, 280.25, 280.5, 319.5, 239.75, "kb4", (-0.0125, 0.045, -0.04125, 0.0085)),
    ("kalibr_models.yaml", "cam1"): (640, 480, 250.5, 250.25, 320.5, 240.25, "ds", (-0.21, 0.58)),
    ("kalibr_models.yaml", "cam2"): (640, 480, 300.0, 299.5, 321.25, 238.5, "eucm", (0.61, 1.05)),
    ("kalibr_models.yaml", "cam3"): (640, 480, 500.5, 500.25, 320.0, 240.0, "radtan", (0, 0, 0, 0, 0)),
    ("kalibr_tumvi_like.yaml", "cam0"): (512, 512, 191.0, 191.0, 255.0, 257.0, "kb4", (0.0035, 0.0007, -0.002, 0.0002)),
    ("basalt_models.json", "cam0"): (848, 800, 285.5, 285.25, 423.75, 399.5, "kb4",
                                     (-0.0075, 0.0455, -0.04375, 0.0084)),
    ("basalt_models.json", "cam1"): (848, 800, 349.5, 349.25, 424.0, 400.5, "ds", (-0.185, 0.59)),
    ("basalt_models.json", "cam2"): (752, 480, 460.75, 459.5, 365.875, 249.25, "eucm", (0.59, 1.125)),
    ("basalt_models.json", "cam3"): (848, 800, 420.5, 421.0, 424.5, 399.5, "radtan", (0, 0, 0, 0, 0)),
    ("basalt_models.json", "cam4"): (848, 800, 610.25, 610.5, 425.0, 398.75, "rational",
                                     (0.85, 0.125, -2.5e-05, 1.5e-05, 0.0025, 1.25, 0.375, 0.025, 0, 0, 0, 0)),
    ("ros_equidistant.yaml", None): (1280, 800, 410.25, 410.75, 639.5, 399.25, "kb4",
                                     (0.0215, -0.0125, 0.0035, -0.00075)),
    ("ros_rational8.yaml", None): (1920, 1200, 1010.5, 1011.25, 959.25, 600.75, "rational",
                                   (0.75, 0.125, -2.5e-05, 1.25e-05, 0.0025, 1.125, 0.3125, 0.0225, 0, 0, 0, 0)),
    ("opencv_fisheye.yml", None): (1024, 768, 330.25, 330.125, 511.5, 383.75, "kb4",
                                   (0.0125, -0.00625, 0.001, -0.00025)),
    ("opencv_thin_prism.xml", None): (1280, 960, 900.5, 901.75, 640.25, 479.5, "rational",
                                      (-0.25, 0.0625, 0.0005, -0.00025, -0.0125, 0, 0, 0, 0.00125, -0.0005, 0.00075,
                                       0.00025)),
    ("appdgen_eucm.json", None): (752, 480, 460.75, 459.375, 365.875, 249.3125, "eucm", (0.59, 1.125)),
}


def _expected(name: str, camera: str | None) -> Calibration:
    """The calibration a fixture holds, from the tables above."""
    if (name, camera) in EXPECTED:
        return Calibration(*EXPECTED[name, camera])
    *head, model, coeffs = MODEL_EXPECTED[name, camera]
    return Calibration(*head, *coeffs, model=model)


def test_every_valid_fixture_is_covered() -> None:
    assert {name for name, _ in [*EXPECTED, *MODEL_EXPECTED]} == {p.name for p in VALID}
    for name in {name for name, _ in MODEL_EXPECTED}:
        assert list_cameras(FIXTURES / name) == sorted({c or "0" for n, c in MODEL_EXPECTED if n == name})


@pytest.mark.parametrize(("name", "camera"), sorted([*EXPECTED, *MODEL_EXPECTED], key=str))
def test_fixture_values(name: str, camera: str | None) -> None:
    assert load(FIXTURES / name, camera=camera) == _expected(name, camera)


@pytest.mark.parametrize("name", ["opencv_fisheye.yml", "opencv_thin_prism.xml"])
def test_model_fixtures_agree_with_cv2(name: str) -> None:
    _same_as_cv2(load(FIXTURES / name), FIXTURES / name)


@pytest.mark.parametrize("name", ["ros_equidistant.yaml", "ros_rational8.yaml"])
def test_ros_model_fixtures_agree_with_yaml(name: str) -> None:
    _same_as_ros_yaml(load(FIXTURES / name), FIXTURES / name)


def _same_as_cv2(calib: Calibration, path: Path) -> None:
    """Assert calib's size, K and coefficients are what cv2.FileStorage reads (past-the-model terms being 0)."""
    _same_vector(calib, *_cv2_read(path, "camera_matrix", "distortion_coefficients", "image_width", "image_height"))


def _same_as_ros_yaml(calib: Calibration, path: Path) -> None:
    """Assert calib's size, K and coefficients are a ROS camera_info's (cv2 cannot read those: no ``dt``)."""
    doc = yaml.safe_load(path.read_text())
    _same_vector(calib, doc["image_width"], doc["image_height"], np.reshape(doc["camera_matrix"]["data"], (3, 3)),
                 np.array(doc["distortion_coefficients"]["data"]))


def _same_vector(calib: Calibration, width: int, height: int, K: np.ndarray, D: np.ndarray) -> None:
    """Assert calib has this size and K, and its coefficients are D's leading terms, the rest of D being 0."""
    assert calib.size == (width, height)
    np.testing.assert_array_equal(calib.K, K)
    d = np.concatenate([D.ravel(), np.zeros(14)])
    np.testing.assert_array_equal(calib.D, d[:calib.D.size])
    assert not d[calib.D.size:].any()


@pytest.mark.parametrize(("name", "keys"), [
    ("opencv.xml", ("camera_matrix", "distortion_coefficients", "image_width", "image_height")),
    ("opencv4.yml", ("Camera_Matrix", "Distortion_Coefficients", "image_Width", "image_Height")),
])
def test_opencv_fixtures_agree_with_cv2(name: str, keys: tuple[str, str, str, str]) -> None:
    _same(load(FIXTURES / name), *_cv2_read(FIXTURES / name, *keys))


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_files_written_by_cv2_filestorage(scratch: Path, suffix: str) -> None:
    calib = Calibration(1280, 720, 1000.123456789, 998.5, 640.25, 360.75, -0.3, 0.1, 1e-4, -2e-4, 0.01)
    path = scratch / f"cv2_written{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", calib.width)
    fs.write("image_height", calib.height)
    fs.write("camera_matrix", calib.K)
    fs.write("distortion_coefficients", calib.D.reshape(5, 1))
    fs.release()
    assert load(path) == calib


@pytest.mark.parametrize("name", [p.name for p in VALID])
def test_detection_ignores_the_extension(scratch: Path, name: str) -> None:
    renamed = scratch / f"{name}.dat"
    shutil.copyfile(FIXTURES / name, renamed)
    cameras = list_cameras(FIXTURES / name)
    assert list_cameras(renamed) == cameras
    assert [load(renamed, c) for c in cameras] == [load(FIXTURES / name, c) for c in cameras]


# --- camera and size selection -----------------------------------------------------------------------------------


@pytest.mark.parametrize("camera", ["02", "2", 2, "image_02", "cam2", "cam02", " 02 "])
def test_kitti_camera_aliases(camera: str | int) -> None:
    assert load(FIXTURES / "kitti_reduced.txt", camera=camera).fx == 961


@pytest.mark.parametrize(("camera", "fx"), [("cam0", 400.5), ("0", 400.5), (0, 400.5), ("cam1", 402.0), (1, 402.0)])
def test_kalibr_camera_aliases(camera: str | int, fx: float) -> None:
    assert load(FIXTURES / "kalibr.yaml", camera=camera).fx == fx


def test_missing_camera_message_names_file_and_cameras() -> None:
    path = FIXTURES / "bad_missing_camera.txt"
    with pytest.raises(AppdgenError) as caught:
        load(path, camera="05")
    assert str(caught.value) == f"{path}: camera '05' not found; available: 00, 01"


@pytest.mark.parametrize(("name", "listed"), [("kitti_reduced.txt", "02, 03"), ("kalibr.yaml", "cam0, cam1"),
                                              ("nuscenes.json", "0, 1"),
                                              ("basalt_models.json", "cam0, cam1, cam2, cam3, cam4")])
def test_several_cameras_need_a_choice(name: str, listed: str) -> None:
    with pytest.raises(AppdgenError, match=f"[0-9] cameras; .*available: {listed}$"):
        load(FIXTURES / name)


def test_single_camera_files_name_their_camera_0() -> None:
    for name in ("appdgen.json", "euroc_sensor.yaml", "opencv.xml", "opencv4.yml", "ros_rational.yaml",
                 "appdgen_eucm.json", "ros_equidistant.yaml", "ros_rational8.yaml", "opencv_fisheye.yml",
                 "opencv_thin_prism.xml"):
        assert list_cameras(FIXTURES / name) == ["0"]
        assert load(FIXTURES / name, camera="0") == load(FIXTURES / name)


def test_size_argument() -> None:
    assert load(FIXTURES / "nuscenes.json", "1", size=(1920, 1080)).size == (1920, 1080)
    assert load(FIXTURES / "kitti_reduced.txt", "02", size=(1392, 512)).size == (1392, 512)
    assert load(FIXTURES / "bad_no_size.yaml", size=(640, 480)).size == (640, 480)
    with pytest.raises(AppdgenError, match=r"size 640x480 given, but the file says 1392x512"):
        load(FIXTURES / "kitti_reduced.txt", "02", size=(640, 480))
    with pytest.raises(AppdgenError, match=r"size.*whole pixels"):
        load(FIXTURES / "nuscenes.json", "0", size=(640.5, 480))


# --- malformed files ---------------------------------------------------------------------------------------------

MALFORMED = [  # file, load arguments, part of the message
    ("bad_empty.txt", {}, "empty file"),
    ("bad_blank.yaml", {}, "empty file"),
    ("bad_garbage.bin", {}, "binary data"),
    ("bad_latin1.txt", {}, "not UTF-8"),
    ("bad_unknown.yaml", {}, "unknown calibration format (read as YAML"),
    ("bad_unknown.json", {}, "unknown calibration format (read as JSON"),
    ("bad_truncated_kitti.txt", {}, "K_02: expected 9 numbers, got 5"),
    ("bad_truncated.yaml", {}, "invalid YAML"),
    ("bad_truncated.json", {}, "invalid JSON"),
    ("bad_truncated.xml", {}, "invalid XML"),
    ("bad_missing_camera.txt", {"camera": "02"}, "camera '02' not found; available: 00, 01"),
    ("bad_missing_camera.txt", {}, "choose one"),
    ("bad_missing_k.txt", {}, "missing key K_02"),
    ("bad_missing_distortion.yaml", {}, "missing key distortion_coefficients"),
    ("bad_missing_intrinsics.yaml", {}, "missing key intrinsics"),
    ("bad_nan.txt", {}, "D_02[1]: expected a finite number, got 'nan'"),
    ("bad_nan.yaml", {}, "camera_matrix.data[0]: expected a finite number"),
    ("bad_inf.yaml", {}, "intrinsics[0]: expected a finite number"),
    ("bad_inf.json", {}, "fx: expected a finite number"),
    ("bad_negative_focal.yaml", {}, "focal lengths must be positive"),
    ("bad_negative_focal.json", {"camera": "1"}, "focal lengths must be positive"),
    ("bad_2x2.yaml", {}, "camera matrix: expected 3x3, got 2x2"),
    ("bad_matrix_count.xml", {}, "camera_matrix.data: expected 9 numbers, got 8"),
    ("bad_transposed.json", {"camera": "0"}, "transposed"),
    ("bad_skew.yaml", {}, "skewed camera matrix"),
    ("bad_fisheye_ros.yaml", {}, "distortion_coefficients (equidistant: k1, k2, k3, k4): expected 4 numbers, got 8"),
    ("bad_distortion_count.yaml", {}, "distortion_coefficients: expected 4 or 5 or 8 or 12 or 14 numbers, got 6"),
    ("bad_tilted.yaml", {}, "OpenCV's tilted model"),
    ("bad_omni.yaml", {}, "camera_model 'omni' is not supported; supported: pinhole, ds, eucm"),
    ("bad_kalibr_fov.yaml", {}, "distortion_model 'fov' is not supported"),
    ("bad_ds_intrinsics.yaml", {}, "intrinsics: camera_model ds expects 6 numbers [xi, alpha, fu, fv, pu, pv], got 4"),
    ("bad_ds_distortion.yaml", {}, "camera_model ds with distortion_model 'radtan' is not supported"),
    ("bad_basalt_type.json", {}, "value0.intrinsics[0].camera_type 'fov' is not supported"),
    ("bad_basalt_missing.json", {}, "missing key value0.intrinsics[0].intrinsics.k3"),
    ("bad_basalt_resolution.json", {}, "value0.resolution: expected a list of 2 [width, height]"),
    ("bad_model.json", {}, "lens model 'omni' is not supported"),
    ("bad_v2_missing.json", {}, "missing key alpha"),
    ("bad_no_size.yaml", {}, "no image size in the file"),
    ("bad_version.json", {}, "version 3; expected 1 or 2"),
    ("bad_no_camera.json", {}, "no camera"),
    ("bad_duplicate.txt", {}, "duplicate key K_02"),
    ("bad_fractional_size.txt", {}, "whole pixels"),
    ("bad_dtd.xml", {}, "DTD"),
    ("bad_yaml_bool.yaml", {}, "invalid YAML"),
    ("bad_yaml_date.yaml", {}, "invalid YAML"),
]


def test_every_malformed_fixture_is_covered() -> None:
    assert {name for name, _, _ in MALFORMED} == {p.name for p in FIXTURES.glob("bad_*")}


@pytest.mark.parametrize(("name", "kwargs", "fragment"), MALFORMED)
def test_malformed_file_raises_one_line_naming_the_file(name: str, kwargs: dict, fragment: str) -> None:
    with pytest.raises(AppdgenError) as caught:
        load(FIXTURES / name, **kwargs)
    message = str(caught.value)
    assert type(caught.value) is AppdgenError
    assert message.startswith(f"{FIXTURES / name}: ") and fragment in message
    assert "\n" not in message and "\r" not in message


@pytest.mark.parametrize("make", [lambda d: d / "absent.yaml", lambda d: d])
def test_missing_file_and_directory(scratch: Path, make) -> None:
    path = make(scratch)
    for call in (load, list_cameras):
        with pytest.raises(AppdgenError, match=re.escape(f"{path}: ")):
            call(path)


# --- writers -----------------------------------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False)
calibrations = st.builds(
    Calibration, st.integers(2, 20000), st.integers(2, 20000),
    st.floats(min_value=1e-300, max_value=1e300), st.floats(min_value=1e-300, max_value=1e300),
    finite, finite, finite, finite, finite, finite, finite,
)


@settings(max_examples=25, deadline=None, database=None)
@given(calibrations)
def test_save_load_round_trip_is_exact_and_cv2_reads_our_yaml(scratch: Path, calib: Calibration) -> None:
    for suffix in (".yaml", ".yml", ".json"):
        save(calib, scratch / f"round{suffix}")
        assert load(scratch / f"round{suffix}") == calib
    _same(calib, *_cv2_read(scratch / "round.yaml", "camera_matrix", "distortion_coefficients",
                            "image_width", "image_height"))


MODELS = ("radtan", "rational", "kb4", "ds", "eucm")


@st.composite
def model_calibrations(draw: st.DrawFn) -> Calibration:
    """A calibration of any model: any finite values the model accepts (ds and eucm bound α and β)."""
    model = draw(st.sampled_from(MODELS))
    size = draw(st.tuples(st.integers(2, 20000), st.integers(2, 20000)))
    focal = draw(st.tuples(*[st.floats(min_value=1e-300, max_value=1e300)] * 2))
    # sparse coefficients too: the rational vector's zero tails pick its YAML length and its model on reading
    coeffs = draw(st.lists(finite | st.floats(0.0, 1.0) | st.just(0.0), min_size=len(lens.params(model)),
                           max_size=len(lens.params(model))))
    try:
        return Calibration(*size, *focal, draw(finite), draw(finite), *coeffs, model=model)
    except AppdgenError:  # outside the model's domain (e.g. eucm's beta <= 0)
        assume(False)


@settings(max_examples=60, deadline=None, database=None)
@given(model_calibrations())
def test_every_model_round_trips(scratch: Path, calib: Calibration) -> None:
    save(calib, scratch / "model.json")
    assert load(scratch / "model.json") == calib
    if calib.model in ("ds", "eucm"):
        with pytest.raises(AppdgenError, match=re.escape(f"model.yaml: OpenCV YAML cannot hold lens model "
                                                         f"'{calib.model}'")):
            save(calib, scratch / "model.yaml")
        return
    save(calib, scratch / "model.yaml")
    back = load(scratch / "model.yaml")
    if calib.model == "rational" and not any(calib.coeffs[5:]):
        assert back == Calibration(*calib.size, *list(calib.params().values())[:9])  # the same lens, as radtan
    else:
        assert back == calib
    _same_as_cv2(back, scratch / "model.yaml")


def test_written_files_look_as_documented(scratch: Path) -> None:
    calib = load(FIXTURES / "appdgen.json")
    save(calib, scratch / "calib.yaml")
    save(calib, scratch / "calib.JSON")
    assert (scratch / "calib.yaml").read_text().startswith("%YAML:1.0\n---\n")
    doc = json.loads((scratch / "calib.JSON").read_text())
    assert doc == {"format": "appdgen-calibration", "version": 2, "model": "radtan", **calib.params(), "width": 1280,
                   "height": 720}
    version_1 = {k: v for k, v in doc.items() if k != "model"} | {"version": 1}
    assert json.loads((FIXTURES / "appdgen.json").read_text()) == version_1  # still read, as radtan
    save(load(FIXTURES / "appdgen_eucm.json"), scratch / "eucm.json")
    assert (scratch / "eucm.json").read_text() == (FIXTURES / "appdgen_eucm.json").read_text()


def test_save_is_atomic_and_leaves_no_temporary_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calib = load(FIXTURES / "opencv.xml")
    target = tmp_path / "calib.json"
    target.write_text("old")

    def fail(*_args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(formats.os, "replace", fail)
    with pytest.raises(AppdgenError, match=re.escape(f"{target}: cannot write: No space left on device")):
        save(calib, target)
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]
    monkeypatch.undo()
    save(calib, target)
    assert load(target) == calib and sorted(tmp_path.iterdir()) == [target]


@pytest.mark.parametrize(("name", "fragment"), [("calib.txt", "cannot write extension '.txt'"),
                                                ("calib", "cannot write extension '(none)'"),
                                                ("missing/calib.yaml", "cannot write: No such file")])
def test_save_errors(tmp_path: Path, name: str, fragment: str) -> None:
    with pytest.raises(AppdgenError, match=re.escape(f"{tmp_path / name}: {fragment}")):
        save(load(FIXTURES / "opencv.xml"), tmp_path / name)


# --- fuzzing: nothing but AppdgenError escapes -------------------------------------------------------------------


def _read_anything(path: Path) -> None:
    """list_cameras and load every camera; any failure must be a one-line AppdgenError naming the file."""
    try:
        for camera in list_cameras(path) or [None]:
            assert isinstance(load(path, camera=camera), Calibration)
    except AppdgenError as exc:
        message = str(exc)
        assert message.startswith(f"{path}: ") and len(message.splitlines()) == 1, message


@FUZZ
@given(st.text(max_size=400))
def test_fuzz_arbitrary_text(scratch: Path, text: str) -> None:
    (scratch / "fuzz.txt").write_text(text, encoding="utf-8", errors="surrogatepass")
    _read_anything(scratch / "fuzz.txt")


@settings(max_examples=25, deadline=None, database=None)
@given(st.binary(max_size=400))
def test_fuzz_arbitrary_bytes(scratch: Path, data: bytes) -> None:
    (scratch / "fuzz.bin").write_bytes(data)
    _read_anything(scratch / "fuzz.bin")


TOKENS = ["nan", ".nan", ".inf", "-1", "0", "-0.0", "1e999", "1" * 400, "", "[", "]", "{", "}", ":", ",", "\n",
          "- ", "  ", "\t", "!!opencv-matrix", "%YAML:1.0\n", "%YAML 1.2\n---\n", "null", "true", "~", "K_02:",
          "S_05: 1 2\n", "cam0:", "cam7: 1\n", '"', "<", "</data>", "&a", "*a", "é", "1_0", "0x10", "!!bool x",
          "2001-13-45", "rows: 0", "1.5"]
NUMBER = re.compile(r"-?[0-9][0-9.eE+\-]*")


@st.composite
def near_valid(draw: st.DrawFn) -> str:
    """A valid fixture's text after one to three mutations: cuts, insertions, truncation, numbers replaced."""
    text = draw(st.sampled_from([p.read_text() for p in VALID]))
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["cut", "insert", "truncate", "number", "number"]))
        if kind == "cut":
            text = text[:at] + text[at + draw(st.integers(1, 40)):]
        elif kind == "insert":
            text = text[:at] + draw(st.sampled_from(TOKENS) | st.text(max_size=6)) + text[at:]
        elif kind == "truncate":
            text = text[:at]
        elif numbers := list(NUMBER.finditer(text)):
            hit = draw(st.sampled_from(numbers))
            text = text[: hit.start()] + draw(st.sampled_from(TOKENS)) + text[hit.end():]
    return text


@settings(max_examples=80, deadline=None, database=None)
@given(near_valid(), st.sampled_from([".txt", ".yaml", ".json", ".xml"]))
def test_fuzz_mutated_valid_files(scratch: Path, text: str, suffix: str) -> None:
    (scratch / f"mutant{suffix}").write_text(text, encoding="utf-8", errors="surrogatepass")
    _read_anything(scratch / f"mutant{suffix}")


KEYS = ["camera_matrix", "distortion_coefficients", "image_width", "image_height", "rows", "cols", "data", "dt",
        "distortion_model", "camera_model", "intrinsics", "distortion_coeffs", "resolution", "cam0", "cam1",
        "camera_intrinsic", "format", "version", "width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2",
        "k3", "k4", "xi", "alpha", "beta", "model", "value0", "camera_type"]
scalars = (st.none() | st.booleans() | st.integers(-3, 2000) | st.floats()
           | st.sampled_from(["pinhole", "radtan", "plumb_bob", "appdgen-calibration", "3", "nan", "", "1 2", "ds",
                             "eucm", "kb4", "equidistant", "fisheye", "none", "omni", "rational_polynomial"]))
documents = st.recursive(
    scalars, lambda inner: st.lists(inner, max_size=9) | st.dictionaries(st.sampled_from(KEYS), inner, max_size=6),
    max_leaves=30,
)


@FUZZ
@given(documents, st.booleans())
def test_fuzz_structured_documents(scratch: Path, doc: object, as_json: bool) -> None:
    path = scratch / "doc.json"
    path.write_text(json.dumps(doc) if as_json else yaml.safe_dump(doc))
    _read_anything(path)
