"""The shipped default calibration: KITTI raw 2011_09_26."""
from __future__ import annotations

import pytest

from appdgen.calibration import Calibration
from appdgen.defaults import DEFAULT_CALIB_PATH, _read_kitti_camera, default_calibration
from appdgen.errors import AppdgenError

KITTI02 = Calibration(1392, 512, 959.791, 956.9251, 696.0217, 224.1806, -0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705)


def test_default_calibration_is_kitti_camera_02():
    assert DEFAULT_CALIB_PATH.is_file()
    assert default_calibration() == KITTI02
    assert default_calibration(2) == KITTI02
    assert default_calibration("00").fx == pytest.approx(984.2439)


def test_kitti_reader_names_what_is_missing(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("S_02: 1392 512\nK_02: 1 0 0 0 1 0 0 0 1\n")
    with pytest.raises(AppdgenError, match="no entry D_02"):
        _read_kitti_camera(path, "02")
    with pytest.raises(AppdgenError, match="no entry S_07"):
        default_calibration("07")
