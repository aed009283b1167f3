"""appdgen manifest: the shipped KITTI raw split, split files, and image lists from tiny fake KITTI / nuScenes trees."""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import ROOT

from appdgen.cli import main
from appdgen.errors import AppdgenError
from appdgen.sources.files import list_images
from appdgen.sources.manifest import kitti_manifests, list_line, read_split_file, split_of, write_list

SPLIT_FILE = ROOT / "manifests" / "kitti_raw_split.txt"
# A 4x2 camera: small enough for 4x2 fake images, valid for the KITTI reader.
CALIB = "S_02: 4 2\nK_02: 5 0 2 0 5 1 0 0 1\nD_02: 0 0 0 0 0\nS_03: 4 2\nK_03: 5 0 2 0 5 1 0 0 1\nD_03: 0 0 0 0 0\n"


def image(path: Path, size: tuple[int, int] = (4, 2)) -> Path:
    """A black PNG of size (width, height)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.zeros((size[1], size[0], 3), np.uint8))
    return path


def drive(root: Path, name: str, frames: int = 2, camera: str = "02", suffix: str = "extract",
          size: tuple[int, int] = (4, 2)) -> list[Path]:
    """Frames of one fake drive <root>/<day>/<name>_<suffix>/image_<camera>/data/*.png."""
    folder = root / name[:10] / f"{name}_{suffix}" / f"image_{camera}" / "data"
    return [image(folder / f"{i:010d}.png", size) for i in range(frames)]


@pytest.fixture
def kitti(tmp_path: Path) -> Path:
    """Two days with calibration files (two drives, one drive) and a third day without one."""
    root = tmp_path / "kitti"
    for name in ("2011_09_26_drive_0001", "2011_09_26_drive_0005", "2011_09_28_drive_0002",
                 "2011_10_03_drive_0027"):
        drive(root, name)
    drive(root, "2011_09_26_drive_0001", camera="03")
    for day in ("2011_09_26", "2011_09_28"):
        (root / day / "calib_cam_to_cam.txt").write_text(CALIB)
    return root


def run(*args: object) -> tuple[int, str]:
    """Run the CLI; (exit code, stdout + stderr)."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    return result.exit_code, result.output


# --- the shipped split -----------------------------------------------------------------------------------------


def test_shipped_split_is_the_papers() -> None:
    rules = read_split_file(SPLIT_FILE)
    assert all(re.fullmatch(r"\d{4}_\d{2}_\d{2}_drive_\d{4}", name) for name in rules)
    assert Counter(name[:10] for name in rules) == {"2011_09_26": 46, "2011_09_28": 93, "2011_09_29": 4,
                                                   "2011_09_30": 8, "2011_10_03": 5}
    assert {split for name, split in rules.items() if name.startswith("2011_09_26")} == {"train"}
    assert {split for name, split in rules.items() if not name.startswith("2011_09_26")} == {"test"}
    assert "2011_09_26_drive_0001" in rules and "2011_10_03_drive_0058" in rules


# --- split files -----------------------------------------------------------------------------------------------


def test_split_file_rules(tmp_path: Path) -> None:
    path = tmp_path / "split.txt"
    path.write_text("# comment\n\n2011_09_26 train  # the whole day\n2011_09_26_drive_0005 val\n")
    rules = read_split_file(path)
    assert rules == {"2011_09_26": "train", "2011_09_26_drive_0005": "val"}
    assert split_of("2011_09_26_drive_0001", rules, path) == "train"
    assert split_of("2011_09_26_drive_0005", rules, path) == "val"  # the drive's line wins
    assert split_of("2011_09_28_drive_0001", None) == "2011_09_28"  # no split file: the day
    with pytest.raises(AppdgenError, match=r"split.txt: no line for drive 2011_09_28_drive_0001 or its day"):
        split_of("2011_09_28_drive_0001", rules, path)


@pytest.mark.parametrize("text, message", [
    ("2011_09_26_drive_0001\n", r"split.txt:1: expected 'DRIVE SPLIT' or 'DAY SPLIT'"),
    ("x\n2011_09_26_drive_0001 a b\n", r"split.txt:1: expected"),
    ("2011_09_26_drive_1 train\n", r"split.txt:1: expected"),
    ("2011_09_26 train\n2011_09_26 test\n", r"split.txt:2: 2011_09_26 is listed twice"),
    ("# nothing\n", r"split.txt: split file names no drive or day"),
])
def test_bad_split_files(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "split.txt").write_text(text)
    with pytest.raises(AppdgenError, match=message):
        read_split_file(tmp_path / "split.txt")


# --- KITTI lists -----------------------------------------------------------------------------------------------


def test_one_list_per_day_with_the_papers_split(kitti: Path, tmp_path: Path) -> None:
    lists = kitti_manifests(kitti, "02", tmp_path / "lists" / "kitti_02.txt", SPLIT_FILE)
    assert [(d.day, d.drives, d.splits) for d in lists] == [
        ("2011_09_26", 2, {"train": 4}), ("2011_09_28", 1, {"test": 2}), ("2011_10_03", 1, {"test": 2})]
    assert [d.path.name for d in lists] == [f"kitti_02_{day}.txt" for day in ("2011_09_26", "2011_09_28",
                                                                              "2011_10_03")]
    assert lists[0].calibration == kitti / "2011_09_26" / "calib_cam_to_cam.txt"
    images = list_images(str(lists[0].path))  # what appdgen build --images reads back
    assert [(i.path.parent.parent.parent.name, i.split) for i in images] == \
        [("2011_09_26_drive_0001_extract", "train")] * 2 + [("2011_09_26_drive_0005_extract", "train")] * 2
    assert all(i.path.is_file() and Path(i.name).is_absolute() for i in images)  # the list lives elsewhere


def test_lists_inside_the_tree_use_relative_paths(kitti: Path) -> None:
    lists = kitti_manifests(kitti, "3", kitti / "kitti_03.txt")
    assert [(d.day, d.camera, d.splits) for d in lists] == [("2011_09_26", "03", {"2011_09_26": 2})]
    assert (kitti / "kitti_03_2011_09_26.txt").read_text().splitlines()[0] == \
        "2011_09_26/2011_09_26_drive_0001_extract/image_03/data/0000000000.png 2011_09_26"


def test_extract_wins_over_sync(kitti: Path, tmp_path: Path) -> None:
    drive(kitti, "2011_09_28_drive_0002", frames=5, suffix="sync")
    drive(kitti, "2011_09_28_drive_0016", frames=1, suffix="sync")
    lists = kitti_manifests(kitti, "02", tmp_path / "k.txt")
    text = (tmp_path / "k_2011_09_28.txt").read_text()
    assert lists[1].drives == 2 and text.count("drive_0002_extract") == 2 and "drive_0002_sync" not in text
    assert text.count("drive_0016_sync") == 1


def test_rectified_sync_images_are_refused(kitti: Path, tmp_path: Path) -> None:
    drive(kitti, "2011_09_28_drive_0016", suffix="sync", size=(3, 1))
    with pytest.raises(AppdgenError, match=r"0000000000.png: is 3x1, .*calib_cam_to_cam.txt camera 02 is 4x2 "
                                           r"\(rectified _sync images: use the drive's unrectified _extract"):
        kitti_manifests(kitti, "02", tmp_path / "k.txt")


def test_unknown_drive_and_empty_trees(kitti: Path, tmp_path: Path) -> None:
    split = tmp_path / "split.txt"
    split.write_text("2011_09_26 train\n2011_09_28 test\n")
    with pytest.raises(AppdgenError, match=r"no line for drive 2011_10_03_drive_0027"):
        kitti_manifests(kitti, "02", tmp_path / "k.txt", split)
    with pytest.raises(AppdgenError, match=r"no KITTI raw images \(expected <day>/<day>_drive_NNNN_extract/image_01"):
        kitti_manifests(kitti, "01", tmp_path / "k.txt")
    with pytest.raises(AppdgenError, match=r"no such KITTI raw folder"):
        kitti_manifests(tmp_path / "nope", "02", tmp_path / "k.txt")
    with pytest.raises(AppdgenError, match=r"--camera 'left'"):
        kitti_manifests(kitti, "left", tmp_path / "k.txt")


def test_paths_a_list_cannot_hold(tmp_path: Path) -> None:
    assert list_line(tmp_path / "a" / "b.png", tmp_path) == "a/b.png"
    assert list_line(tmp_path / "b.png", tmp_path / "lists") == (tmp_path / "b.png").as_posix()
    for name in ("my\tdata", "#data"):
        with pytest.raises(AppdgenError, match="tabs or line breaks, or starting with '#'"):
            list_line(tmp_path / name / "b.png", tmp_path)


def test_paths_with_spaces_and_hashes_go_on_tab_lines(tmp_path: Path) -> None:
    images = [tmp_path / "my data" / "a #1.png", tmp_path / "plain" / "b.png"]
    for image in images:
        image.parent.mkdir(exist_ok=True)
        image.write_bytes(b"")
    write_list(tmp_path / "list.txt", [(images[0], "train"), (images[1], "test")])
    assert (tmp_path / "list.txt").read_text() == "my data/a #1.png\ttrain\nplain/b.png test\n"
    assert [(i.path, i.name, i.split) for i in list_images(str(tmp_path / "list.txt"))] == [
        (images[0], "my data/a #1.png", "train"), (images[1], "plain/b.png", "test")]


def test_cli_prints_the_calibration_and_build_command_per_day(kitti: Path, tmp_path: Path) -> None:
    output = tmp_path / "kitti_02.txt"
    code, text = run("manifest", kitti, "--camera", "02", "-o", output, "--split-file", SPLIT_FILE)
    assert code == 0, text
    assert f"2011_09_26: 2 drives, 4 images (train 4) -> {tmp_path / 'kitti_02_2011_09_26.txt'}" in text
    assert "2011_09_28: 1 drive, 2 images (test 2) -> " in text
    assert (f"  appdgen build --calib {kitti / '2011_09_28' / 'calib_cam_to_cam.txt'} --camera 02 "
            f"--images {tmp_path / 'kitti_02_2011_09_28.txt'} --out OUT_2011_09_28") in text
    assert f"warning: {kitti / '2011_10_03' / 'calib_cam_to_cam.txt'} is missing" in text


@pytest.mark.parametrize("args", [[], ["ROOT", "--nuscenes", "ROOT"]])
def test_cli_needs_one_tree(tmp_path: Path, args: list[str]) -> None:
    code, text = run("manifest", *[str(tmp_path) if a == "ROOT" else a for a in args], "-o", tmp_path / "x.txt")
    assert code == 2 and "give a KITTI_ROOT or --nuscenes ROOT" in text


# --- nuScenes --------------------------------------------------------------------------------------------------


def test_nuscenes_channel_list(tmp_path: Path) -> None:
    root = tmp_path / "nuscenes"
    for name in ("n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg",
                 "n015-2018-07-18-11-07-57+0800__CAM_FRONT__1531883530412470.jpg"):
        image(root / "samples" / "CAM_FRONT" / name)
    image(root / "samples" / "CAM_BACK" / "n008__CAM_BACK__1.jpg")
    code, text = run("manifest", "--nuscenes", root, "--channel", "CAM_FRONT", "-o", root / "front.txt")
    assert code == 0 and text.startswith(f"2 images -> {root / 'front.txt'}"), text
    assert [(i.name, i.split) for i in list_images(str(root / "front.txt"))] == [
        ("samples/CAM_FRONT/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg", "all"),
        ("samples/CAM_FRONT/n015-2018-07-18-11-07-57+0800__CAM_FRONT__1531883530412470.jpg", "all")]
    code, text = run("manifest", "--nuscenes", root, "--channel", "CAM_LEFT", "-o", root / "left.txt")
    assert code == 2 and "CAM_LEFT: no nuScenes images (*.jpg)" in text
