"""Image lists for `appdgen build --images` from local dataset trees: KITTI raw (one list per day) and nuScenes.

A list holds 'PATH SPLIT' lines (see sources._read_list). One build uses one reference calibration, and every
KITTI day has its own calib_cam_to_cam.txt, so KITTI gets one list per day, to be built with that day's file.
"""
from __future__ import annotations

import os
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from appdgen.calib.formats import load
from appdgen.errors import AppdgenError
from appdgen.sources.files import KITTI_DAY, KITTI_DRIVE
from appdgen.sources.headers import image_size
from appdgen.util.atomic import write_file

CALIBRATION = "calib_cam_to_cam.txt"
_FOLDER = re.compile(f"({KITTI_DRIVE})_(extract|sync)")  # a drive's unrectified (_extract) or rectified folder
_RULE = re.compile(f"{KITTI_DRIVE}|{KITTI_DAY}")
_NEEDS_TAB = re.compile(r"[\s#]")  # a 'PATH SPLIT' line splits on whitespace and cuts at '#': use PATH<TAB>SPLIT
_UNLISTABLE = re.compile(r"[\t\n\r\0]")  # no list line can hold these


@dataclass(frozen=True)
class DayList:
    """One KITTI day's image list: where it went, the calibration to build it with, and what it holds."""

    day: str
    camera: str
    path: Path
    calibration: Path
    drives: int
    splits: dict[str, int]

    @property
    def images(self) -> int:
        """Number of images listed."""
        return sum(self.splits.values())


def read_split_file(path: Path) -> dict[str, str]:
    """'NAME SPLIT' lines, NAME a KITTI drive or day → {NAME: SPLIT}; AppdgenError naming file and line."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise AppdgenError(f"{path}: cannot read split file ({getattr(exc, 'strerror', None) or exc})") from None
    rules: dict[str, str] = {}
    for number, line in enumerate(lines, 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) != 2 or not _RULE.fullmatch(fields[0]):
            raise AppdgenError(f"{path}:{number}: expected 'DRIVE SPLIT' or 'DAY SPLIT' (e.g. "
                               f"'2011_09_26_drive_0001 train'), got {line.strip()!r}")
        if fields[0] in rules:
            raise AppdgenError(f"{path}:{number}: {fields[0]} is listed twice")
        rules[fields[0]] = fields[1]
    if not rules:
        raise AppdgenError(f"{path}: split file names no drive or day")
    return rules


def split_of(drive: str, rules: dict[str, str] | None, where: Path | None = None) -> str:
    """A drive's split: its own line, else its day's line; its day when there is no split file."""
    day = drive[:10]
    if rules is None:
        return day
    split = rules.get(drive, rules.get(day))
    if split is None:
        raise AppdgenError(f"{where}: no line for drive {drive} or its day (add '{drive} SPLIT' or '{day} SPLIT')")
    return split


def kitti_drives(root: Path, camera: str) -> dict[str, dict[str, Path]]:
    """{day: {drive: image folder}} of <root>/<day>/<drive>_{extract,sync}/image_<camera>/data."""
    if not root.is_dir():
        raise AppdgenError(f"{root}: no such KITTI raw folder")
    days: dict[str, dict[str, Path]] = {}
    for folder in sorted(root.glob(f"*/*_drive_*/image_{camera}/data")):
        drive_folder = folder.parent.parent
        match = _FOLDER.fullmatch(drive_folder.name)
        if not match or drive_folder.parent.name != match.group(1)[:10]:
            continue
        drive, kind = match.groups()
        drives = days.setdefault(drive[:10], {})
        if kind == "extract" or drive not in drives:  # _extract holds the unrectified images: it wins over _sync
            drives[drive] = folder
    return days


def list_line(image: Path, folder: Path) -> str:
    """An image's path for a list in `folder`: relative when below it, else absolute (never through '..')."""
    absolute = Path(os.path.abspath(image))
    try:
        text = absolute.relative_to(os.path.abspath(folder)).as_posix()
    except ValueError:
        text = absolute.as_posix()
    if _UNLISTABLE.search(text) or text.lstrip().startswith("#"):
        raise AppdgenError(f"{image}: image lists cannot hold paths with tabs or line breaks, or starting with "
                           f"'#'; link the dataset elsewhere")
    return text


def write_list(path: Path, entries: list[tuple[Path, str]]) -> None:
    """Write 'PATH SPLIT' lines ('PATH<TAB>SPLIT' for paths with spaces or '#') atomically (AppdgenError naming the
    list when it cannot be written)."""
    lines = [(list_line(image, path.parent), split) for image, split in entries]
    text = "".join(f"{line}{chr(9) if _NEEDS_TAB.search(line) else ' '}{split}\n" for line, split in lines)
    write_file(path, text.encode("utf-8"))


def day_list_path(output: Path, day: str) -> Path:
    """Where a day's list goes: 'kitti_02.txt' → 'kitti_02_2011_09_26.txt' beside it."""
    return output.with_name(f"{output.stem}_{day}{output.suffix or '.txt'}")


def kitti_manifests(root: Path, camera: str, output: Path, split_file: Path | None = None) -> list[DayList]:
    """Write one image list per KITTI raw day found under `root` and say which calibration goes with each."""
    if not re.fullmatch(r"\d{1,2}", camera):
        raise AppdgenError(f"--camera {camera!r}: expected a KITTI camera number, e.g. 02")
    camera = f"{int(camera):02d}"
    rules = read_split_file(split_file) if split_file is not None else None
    days = kitti_drives(root, camera)
    lists = []
    for day, drives in sorted(days.items()):
        calibration = root / day / CALIBRATION
        entries = [(image, split_of(drive, rules, split_file))
                   for drive, folder in sorted(drives.items()) for image in sorted(folder.glob("*.png"))]
        if not entries:
            continue
        _check_size(drives, calibration, camera)
        write_list(day_list_path(output, day), entries)
        splits = dict(sorted(Counter(split for _, split in entries).items()))
        lists.append(DayList(day, camera, day_list_path(output, day), calibration, len(drives), splits))
    if not lists:
        raise AppdgenError(f"{root}: no KITTI raw images (expected <day>/<day>_drive_NNNN_extract/"
                           f"image_{camera}/data/*.png)")
    return lists


def _check_size(drives: dict[str, Path], calibration: Path, camera: str) -> None:
    """Each drive's first image must have the calibration's raw size (skipped when the day has no calibration)."""
    if not calibration.is_file():
        return
    size = load(calibration, camera=camera).size
    for folder in drives.values():
        first = min(folder.glob("*.png"), default=None)
        actual = image_size(first) if first else size
        if actual != size:
            hint = " (rectified _sync images: use the drive's unrectified _extract folder)" \
                if folder.parent.parent.name.endswith("_sync") else ""
            raise AppdgenError(f"{first}: is {actual[0]}x{actual[1]}, {calibration} camera {camera} is "
                               f"{size[0]}x{size[1]}{hint}")


def nuscenes_manifest(root: Path, channel: str, output: Path) -> int:
    """Write the list of <root>/samples/<channel>/*.jpg (split 'all'); returns the number of images."""
    folder = root / "samples" / channel
    images = sorted(folder.glob("*.jpg"))
    if not images:
        raise AppdgenError(f"{folder}: no nuScenes images (*.jpg)")
    write_list(output, [(image, "all") for image in images])
    return len(images)
