"""Raw image sources: folders, globs and list files → a sorted list of images with their split."""
from __future__ import annotations

import glob
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2

from appdgen.errors import AppdgenError

if TYPE_CHECKING:
    from appdgen.dataset.recordings import Frame

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
SPLIT_BY = ("none", "parent", "day", "drive", "recording")
KITTI_DAY = r"\d{4}_\d{2}_\d{2}"  # a KITTI raw recording day, e.g. 2011_09_26
KITTI_DRIVE = KITTI_DAY + r"_drive_\d{4}"  # a drive of that day, e.g. 2011_09_26_drive_0001
_DAY = re.compile(f"({KITTI_DAY})")
_DRIVE = re.compile(f"({KITTI_DRIVE})")
_KITTI_CAMERA = re.compile(r"image_(\d{2})")
_PNG_START = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the empty IEND chunk every complete PNG ends with
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # IHDR colour type → channels (3: palette, read as colour)
_JPEG_START, _JPEG_END = b"\xff\xd8", b"\xff\xd9"
_JPEG_TAIL = 1024  # bytes searched for the end-of-image marker (some writers append a few bytes after it)


@dataclass(frozen=True)
class RawImage:
    """One raw image: its path, the path as recorded in the index, and its split name; for a frame of a
    recording (bag, video) the recording's path and the frame."""

    path: Path
    name: str
    split: str
    frame: Frame | None = None


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
    """Lines `PATH [SPLIT]` (whitespace-separated) or `PATH<TAB>SPLIT` (a path holding spaces or '#') of a list
    file; relative paths are relative to the list's folder."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise AppdgenError(f"{path}: cannot read image list ({exc})") from None
    images = []
    for number, line in enumerate(lines, 1):
        fields = _list_fields(line, f"{path}:{number}")
        if not fields:
            continue
        image = Path(fields[0]) if Path(fields[0]).is_absolute() else path.parent / fields[0]
        split = fields[1] if len(fields) == 2 else _split_of(Path(fields[0]), split_by)
        images.append(RawImage(image, fields[0], split))
    return images


def _list_fields(line: str, where: str) -> list[str]:
    """[PATH] or [PATH, SPLIT] of one list line; [] for blank and comment lines."""
    if "\0" in line:  # no file name holds one; the OS would refuse it later with a ValueError
        raise AppdgenError(f"{where}: NUL byte in the line")
    if line.lstrip().startswith("#"):
        return []
    if "\t" in line:  # tab-separated: the path is taken verbatim, spaces and '#' included
        fields = [f for f in line.split("\t") if f.strip()]
        fields[1:] = [f.strip() for f in fields[1:]]
    else:
        fields = line.split("#", 1)[0].split()
    if len(fields) > 2 or (len(fields) == 2 and not fields[1]):
        raise AppdgenError(f"{where}: expected 'PATH [SPLIT]' or 'PATH<TAB>SPLIT', got {line.strip()!r}")
    return fields


def _split_of(relative: Path, split_by: str) -> str:
    """The split name of an image path under a --split-by rule ('all' when none applies)."""
    text = relative.as_posix()
    if split_by == "recording":  # a folder of images: the folder each image lies in
        return relative.parent.as_posix() if len(relative.parts) > 1 else "all"
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


@dataclass(frozen=True)
class ImageHeader:
    """What a raw image's header says: size (pixels) and channels (1 grey, 3 colour, 2 or 4 with alpha)."""

    width: int
    height: int
    channels: int

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from the image's header; AppdgenError naming the file."""
    return image_header(path).size


def image_header(path: Path) -> ImageHeader:
    """Size and channels from the PNG/JPEG header (else by decoding), after check_complete; errors name the file."""
    check_complete(path)
    try:
        with open(path, "rb") as handle:
            header = stream_header(handle)
            if header:
                return header
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise AppdgenError(f"{path}: not a readable image")
    return ImageHeader(image.shape[1], image.shape[0], 1 if image.ndim == 2 else image.shape[2])


def stream_header(handle) -> ImageHeader | None:
    """Size and channels from the PNG/JPEG header of an open binary file (or BytesIO) at its start, else None."""
    head = handle.read(32)
    if head.startswith(_PNG_START) and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return ImageHeader(width, height, _PNG_CHANNELS.get(head[25], 0))
    if head.startswith(_JPEG_START):
        return _jpeg_header(handle)
    return None


def truncation(data: bytes) -> str | None:
    """Why encoded PNG/JPEG bytes are cut short (no IEND chunk, no end-of-image marker near the end), or None."""
    if data.startswith(_PNG_START) and not data.endswith(_PNG_END):
        return "truncated PNG (no IEND chunk at its end)"
    if data.startswith(_JPEG_START) and _JPEG_END not in data[-_JPEG_TAIL:]:
        return f"truncated JPEG (no end-of-image marker in its last {_JPEG_TAIL} bytes)"
    return None


def check_complete(path: Path) -> None:
    """Refuse a PNG without its closing IEND chunk or a JPEG without its end-of-image marker: a cut-off copy has
    a good header and decodes without error, the missing rows grey."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
            size = handle.seek(0, 2)
            handle.seek(max(size - _JPEG_TAIL, len(head)))
            problem = truncation(head + handle.read())
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    if problem:
        raise AppdgenError(f"{path}: {problem}")


def _jpeg_header(handle) -> ImageHeader | None:
    """Size and components from a JPEG's first start-of-frame marker, or None when the header is odd."""
    handle.seek(2)
    while True:
        marker = handle.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        if 0xC0 <= marker[1] <= 0xCF and marker[1] not in (0xC4, 0xC8, 0xCC):
            data = handle.read(8)  # length, precision, height, width, components
            if len(data) < 8:
                return None
            return ImageHeader(struct.unpack(">H", data[5:7])[0], struct.unpack(">H", data[3:5])[0], data[7])
        length = handle.read(2)
        if len(length) < 2:
            return None
        handle.seek(struct.unpack(">H", length)[0] - 2, 1)


def check_images(images: list[RawImage], size: tuple[int, int], skip_bad: bool) -> tuple[list[RawImage], list[dict]]:
    """Images of the calibration's raw size, complete, grey or colour; the others refused (first named) or, with
    skip_bad, dropped and returned as {"path", "problem"} (cheap: headers and file ends only)."""
    kept, dropped = [], []
    for image in images:
        try:
            header = image_header(image.path)
            problem = _header_problem(header, size)
        except AppdgenError as exc:
            problem = str(exc).split(": ", 1)[-1]
        if problem is None:
            kept.append(image)
        elif skip_bad:
            dropped.append({"path": str(image.path), "problem": problem})
        else:
            raise AppdgenError(f"{image.path}: {problem} (use --skip-bad to skip such images)")
    if not kept:
        first = f"{dropped[0]['path']}: {dropped[0]['problem']}" if dropped else "none given"
        raise AppdgenError(f"no usable image left: {first}")
    return kept, dropped


def all_grey(images: list[RawImage]) -> bool:
    """Whether every image file is grey (one channel in its header)."""
    return all(image_header(image.path).channels == 1 for image in images)


def _header_problem(header: ImageHeader, size: tuple[int, int]) -> str | None:
    """Why an image with this header cannot be a raw image of a camera of `size`, or None."""
    if header.size != size:
        return f"is {header.width}x{header.height}, the calibration {size[0]}x{size[1]}"
    if header.channels not in (1, 3):
        return (f"has {header.channels} channels (alpha or CMYK); appdgen reads grey (1) or colour (3) images")
    return None
