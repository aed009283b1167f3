"""The shipped default calibration: KITTI raw 2011_09_26."""
from __future__ import annotations

import pytest
from conftest import KITTI_2011_09_26

from appdgen.calib.defaults import DEFAULT_CALIB_PATH, default_calibration
from appdgen.errors import AppdgenError


@pytest.mark.parametrize("camera", sorted(KITTI_2011_09_26))
def test_default_calibration_is_the_published_kitti_file(camera):
    assert DEFAULT_CALIB_PATH.is_file()
    assert default_calibration(camera) == KITTI_2011_09_26[camera]
    assert default_calibration(int(camera)) == KITTI_2011_09_26[camera]


def test_missing_camera_names_the_file():
    with pytest.raises(AppdgenError, match="camera '07' not found"):
        default_calibration("07")
