"""Image files as sources: folders, globs and list files → a sorted list of images with their split, checked by
their headers."""
from __future__ import annotations

import glob
import re
from pathlib import Path

from appdgen.errors import AppdgenError
from appdgen.sources.decode import decode_bytes, is_jpeg
from appdgen.sources.frames import RawImage
from appdgen.sources.headers import header_problem, image_header

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
SPLIT_BY = ("none", "parent", "day", "drive", "recording")
KITTI_DAY = r"\d{4}_\d{2}_\d{2}"  # a KITTI raw recording day, e.g. 2011_09_26
KITTI_DRIVE = KITTI_DAY + r"_drive_\d{4}"  # a drive of that day, e.g. 2011_09_26_drive_0001
_DAY = re.compile(f"({KITTI_DAY})")
_DRIVE = re.compile(f"({KITTI_DRIVE})")
_KITTI_CAMERA = re.compile(r"image_(\d{2})")


def list_images(spec: str, split_by: str = "none") -> list[RawImage]:
    """Images from a folder (recursive), a glob pattern or a list file (`path [split]` per line), sorted."""
    if split_by not in SPLIT_BY:
        raise AppdgenError(f"--split-by {split_by!r}: expected one of {', '.join(SPLIT_BY)}")
    path = Path(spec)
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
        images = [RawImage(p, p.relative_to(path).as_posix(), split_of(p.relative_to(path), split_by)) for p in files]
        where = f"{spec}: folder has no images ({', '.join(IMAGE_SUFFIXES)})"
    elif any(ch in spec for ch in "*?["):
        files = sorted(Path(p) for p in glob.glob(spec, recursive=True) if Path(p).suffix.lower() in IMAGE_SUFFIXES)
        images = [RawImage(p, p.as_posix(), split_of(p, split_by)) for p in files]
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
        split = fields[1] if len(fields) == 2 else split_of(Path(fields[0]), split_by)
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


def split_of(relative: Path, split_by: str) -> str:
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


def check_images(images: list[RawImage], size: tuple[int, int], skip_bad: bool) -> tuple[list[RawImage], list[dict]]:
    """Images of the calibration's raw size, complete, grey or colour; the others refused (first named) or, with
    skip_bad, dropped and returned as {"path", "problem"} (headers and file ends only; with skip_bad also each
    JPEG's body, decoded strictly once here, so that no worker meets a corrupt one it would have to stop at)."""
    kept, dropped = [], []
    for image in images:
        try:
            header = image_header(image.path)
            problem = header_problem(header, size) or (_jpeg_body_problem(image.path) if skip_bad else None)
        except AppdgenError as exc:
            problem = str(exc).split(": ", 1)[-1]
        if problem is None:
            kept.append(image)
        elif skip_bad:
            dropped.append({"path": str(image.path), "problem": problem})
        else:
            raise AppdgenError(f"{image.path}: {problem}{_missing_hint(image)} (use --skip-bad to skip such images)")
    if not kept:
        first = f"{dropped[0]['path']}: {dropped[0]['problem']}" if dropped else "none given"
        raise AppdgenError(f"no usable image left: {first}")
    return kept, dropped


def _missing_hint(image: RawImage) -> str:
    """For a missing file named by a relative path: where such a path is read from (a list file's folder)."""
    if image.frame is not None or image.path.exists() or Path(image.name).is_absolute():
        return ""
    return "; relative paths in a list file are read from the list's folder"


def _jpeg_body_problem(path: Path) -> str | None:
    """Why a JPEG file's body does not decode strictly (corrupt data), or None (also for other formats)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"cannot read image ({exc.strerror or exc})"
    if not is_jpeg(data):
        return None
    try:
        decode_bytes(data, str(path))
    except AppdgenError as exc:
        return str(exc).removeprefix(f"{path}: ")
    return None


def all_grey(images: list[RawImage]) -> bool:
    """Whether every image file is grey (one channel in its header)."""
    return all(image_header(image.path).channels == 1 for image in images)
