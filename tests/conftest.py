"""Shared fixtures: published KITTI calibrations (embedded), ../shared/data when present, and small builds."""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from appdgen.calib.calibration import Calibration
from appdgen.sampling.ranges import PAPER_RANGES  # noqa: F401  (re-exported to the tests)
from helpers import Setup, kitti_text, raw_image, run_cli, run_with_full_disk, scaled, write_png

ROOT = Path(__file__).resolve().parents[1]

# KITTI raw 2011_09_26 calib_cam_to_cam.txt, cameras 00–03 (published values; ../shared/data/kitti/values.csv).
KITTI_2011_09_26 = {
    "00": Calibration(1392, 512, 984.2439, 980.8141, 690.0, 233.1966,
                      -0.3728755, 0.2037299, 0.002219027, 0.001383707, -0.07233722),
    "01": Calibration(1392, 512, 989.5267, 987.8386, 702.0, 245.559,
                      -0.3644661, 0.1790019, 0.001148107, -0.0006298563, -0.05314062),
    "02": Calibration(1392, 512, 959.791, 956.9251, 696.0217, 224.1806,
                      -0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705),
    "03": Calibration(1392, 512, 903.7596, 901.9653, 695.7519, 224.2509,
                      -0.3639558, 0.1788651, 0.0006029694, -0.0003922424, -0.0538246),
}


# `heavy` tests run only when asked for: --heavy, or a -m expression naming heavy other than as 'not heavy'. An
# addopts "-m 'not heavy'" was replaced by any -m typed by hand (-m "not slow" then ran the minutes-long tests).
HEAVY = "heavy"


def pytest_addoption(parser: pytest.Parser) -> None:
    """--heavy: also run the minutes-long `heavy` tests."""
    parser.addoption("--heavy", action="store_true", help="also run the minutes-long tests marked heavy")


def heavy_requested(config: pytest.Config) -> bool:
    """Whether this run asked for the heavy tests (--heavy, or -m naming heavy without 'not')."""
    expression = config.getoption("markexpr") or ""
    return config.getoption("--heavy") or bool(re.search(rf"(?<!not )\b{HEAVY}\b", expression))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Deselect the heavy tests unless they were asked for."""
    if heavy_requested(config):
        return
    heavy = [item for item in items if item.get_closest_marker(HEAVY)]
    if heavy:
        config.hook.pytest_deselected(items=heavy)
        items[:] = [item for item in items if not item.get_closest_marker(HEAVY)]


def shared_data() -> Path | None:
    """The ../shared/data folder (or $APPDGEN_SHARED_DATA) when present."""
    path = Path(os.environ.get("APPDGEN_SHARED_DATA", ROOT.parent / "shared" / "data"))
    return path if path.is_dir() else None


@pytest.fixture
def shared() -> Path:
    """../shared/data, or skip the test cleanly when it is absent."""
    path = shared_data()
    if path is None:
        pytest.skip("../shared/data not present")
    return path


@pytest.fixture
def kitti02() -> Calibration:
    """KITTI 2011_09_26 camera 02, the paper's reference camera."""
    return KITTI_2011_09_26["02"]


@pytest.fixture(scope="session")
def small_camera() -> Calibration:
    """KITTI camera 02 at 1/8 size (174x64): K scaled, distortion kept, so builds are tiny and fast."""
    return scaled(KITTI_2011_09_26["02"], 8)


@pytest.fixture(scope="session")
def setup(tmp_path_factory: pytest.TempPathFactory, small_camera: Calibration) -> Setup:
    """The small camera's KITTI-format calibration file and three raw images, with the standard build options."""
    root = tmp_path_factory.mktemp("inputs")
    calib = root / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"02": small_camera}))
    for i in range(3):
        write_png(root / "images" / f"{i:010d}.png", raw_image(small_camera.size, i))
    return Setup(calib, root / "images")


def _build(tmp_path_factory: pytest.TempPathFactory, setup: Setup, jobs: int) -> Path:
    """The standard build, uninterrupted, run from this process."""
    out = tmp_path_factory.mktemp(f"jobs{jobs}") / "out"
    result = run_cli(setup.args(out, jobs=jobs))
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def reference_build(tmp_path_factory: pytest.TempPathFactory, setup: Setup) -> Path:
    """The standard build with --jobs 1 (in this process): what every other way must reproduce."""
    return _build(tmp_path_factory, setup, 1)


@pytest.fixture(scope="session")
def loky_build(tmp_path_factory: pytest.TempPathFactory, setup: Setup) -> Path:
    """The standard build with --jobs 2 (two loky worker processes)."""
    return _build(tmp_path_factory, setup, 2)


@pytest.fixture(scope="session")
def interrupted_build(setup: Setup, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The standard build stopped with shards 0 and 1 done: the disk 'fills up' at the 6th write (shard 2's tar)."""
    out = tmp_path_factory.mktemp("interrupted") / "out"
    assert run_with_full_disk(setup.args(out), 6).exit_code == 2
    return out
