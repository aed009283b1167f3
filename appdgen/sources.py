"""Raw image sources: folders, globs and list files → a sorted list of images with their split."""
from __future__ import annotations

import glob
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import cv2

from appdgen.errors import AppdgenError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
SPLIT_BY = ("none", "parent", "day", "drive")
KITTI_DAY = r"\d{4}_\d{2}_\d{2}"  # a KITTI raw recording day, e.g. 2011_09_26
KITTI_DRIVE = KITTI_DAY + r"_drive_\d{4}"  # a drive of that day, e.g. 2011_09_26_drive_0001
_DAY = re.compile(f"({KITTI_DAY})")
_DRIVE = re.compile(f"({KITTI_DRIVE})")
_KITTI_CAMERA = re.compile(r"image_(\d{2})")
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the empty IEND chunk every complete PNG ends with


@dataclass(frozen=True)
class RawImage:
    """One raw image: its path, the path as recorded in the index, and its split name."""

    path: Path
    name: str
    split: str


def list_images(spec: str, split_by: str = "none") -> list[RawImage]:
    """Images from a folder (recursive), a glob pattern or a list file (`path [split]` per line), sorted."""
    if split_by not in SPLIT_BY:
        raise AppdgenError(f"--split-by {split_by!r}: expected one of {', '.join(SPLIT_BY)}")
    path = Path(spec)
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
        images = [RawImage(p, p.relative_to(path).as_posix(), _split_of(p.relative_to(path), split_by)) for p in files]
        where = f"{spec}: folder has no images ({', '.join(IMAGE_SUFFIXES)})"
    elif any(ch in spec for ch in "*?["):
        files = sorted(Path(p) for p in glob.glob(spec, recursive=True) if Path(p).suffix.lower() in IMAGE_SUFFIXES)
        images = [RawImage(p, p.as_posix(), _split_of(p, split_by)) for p in files]
        where = f"{spec}: pattern matches no images"
    elif path.is_file():
        images = _read_list(path, split_by)
        where = f"{spec}: list names no images"
    else:
        raise AppdgenError(f"{spec}: no such folder, list file or glob pattern")
    if not images:
        raise AppdgenError(where)
    _refuse_duplicates(images, spec)
    return images


def _read_list(path: Path, split_by: str) -> list[RawImage]:
    """Lines `path [split]` of a list file; relative paths are relative to the list's folder."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise AppdgenError(f"{path}: cannot read image list ({exc})") from None
    images = []
    for number, line in enumerate(lines, 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if "\0" in line:  # no file name holds one; the OS would refuse it later with a ValueError
            raise AppdgenError(f"{path}:{number}: NUL byte in the line")
        if len(fields) > 2:
            raise AppdgenError(f"{path}:{number}: expected 'PATH [SPLIT]', got {line.strip()!r}")
        image = Path(fields[0]) if Path(fields[0]).is_absolute() else path.parent / fields[0]
        split = fields[1] if len(fields) == 2 else _split_of(Path(fields[0]), split_by)
        images.append(RawImage(image, fields[0], split))
    return images


def _split_of(relative: Path, split_by: str) -> str:
    """The split name of an image path under a --split-by rule ('all' when none applies)."""
    text = relative.as_posix()
    if split_by == "parent":
        return relative.parts[0] if len(relative.parts) > 1 else "all"
    if split_by in ("day", "drive"):
        match = (_DAY if split_by == "day" else _DRIVE).search(text)
        return match.group(1) if match else "all"
    return "all"


def _refuse_duplicates(images: list[RawImage], spec: str) -> None:
    """Refuse a source naming one file twice (it would silently weight that image double)."""
    seen: dict[Path, str] = {}
    for image in images:
        key = image.path.resolve()
        if key in seen:
            raise AppdgenError(f"{spec}: image {image.name} is listed twice")
        seen[key] = image.name


def kitti_camera(images: list[RawImage]) -> str | None:
    """The KITTI camera named by `image_0X` folders when all images agree on one, else None."""
    cameras = {m.group(1) for m in (_KITTI_CAMERA.search(i.path.as_posix()) for i in images) if m}
    return cameras.pop() if len(cameras) == 1 else None


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from the PNG/JPEG header, else by decoding; AppdgenError naming the file."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(32)
            if head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR":
                # A cut-off copy has a good header but fails to decode mid-build: refuse it before --out is touched.
                handle.seek(-len(_PNG_END), 2)
                if handle.read() != _PNG_END:
                    raise AppdgenError(f"{path}: truncated PNG (no IEND chunk at its end)")
                return struct.unpack(">II", head[16:24])
            if head.startswith(b"\xff\xd8"):
                size = _jpeg_size(handle)
                if size:
                    return size
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise AppdgenError(f"{path}: not a readable image")
    return image.shape[1], image.shape[0]


def _jpeg_size(handle) -> tuple[int, int] | None:
    """Size from a JPEG's first start-of-frame marker, or None when the header is odd."""
    handle.seek(2)
    while True:
        marker = handle.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        if 0xC0 <= marker[1] <= 0xCF and marker[1] not in (0xC4, 0xC8, 0xCC):
            data = handle.read(7)
            return (struct.unpack(">H", data[5:7])[0], struct.unpack(">H", data[3:5])[0]) if len(data) == 7 else None
        length = handle.read(2)
        if len(length) < 2:
            return None
        handle.seek(struct.unpack(">H", length)[0] - 2, 1)


def check_sizes(images: list[RawImage], size: tuple[int, int], skip_bad: bool) -> tuple[list[RawImage], list[str]]:
    """Images of the calibration's raw size; the others refused (first named) or, with skip_bad, dropped."""
    kept, dropped = [], []
    for image in images:
        try:
            actual = image_size(image.path)
            problem = None if actual == size else f"is {actual[0]}x{actual[1]}, the calibration {size[0]}x{size[1]}"
        except AppdgenError as exc:
            problem = str(exc).split(": ", 1)[-1]
        if problem is None:
            kept.append(image)
        elif skip_bad:
            dropped.append(f"{image.path}: {problem}")
        else:
            raise AppdgenError(f"{image.path}: {problem} (use --skip-bad to skip such images)")
    if not kept:
        raise AppdgenError(f"no usable image left: {dropped[0] if dropped else 'none given'}")
    return kept, dropped
