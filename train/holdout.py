"""The holdout rules, written once for the offline fit (samples of a build) and the online fit (raw frames): which
split validates (--val-split), what a holdout keeps whole (--val-by) and which side each raw image falls on."""
from __future__ import annotations

import hashlib
import posixpath
import re
import sys
from collections.abc import Mapping

from appdgen.sources.files import KITTI_DRIVE
from appdgen.sources.frames import RawImage
from train.errors import TrainError

_DRIVE = re.compile(KITTI_DRIVE)
#: What a holdout keeps together: whole recordings (KITTI drive, else folder), or single raw images.
HOLDOUT_UNITS = ("recording", "image")


def val_choice(val_split: str, has_val: bool) -> str:
    """--val-split resolved: a split name, 'holdout' or 'none'; 'auto' is 'val' when the data has a val split (has_val),
    else 'holdout'."""
    if val_split == "auto":
        return "val" if has_val else "holdout"
    return val_split


def in_holdout(ident: str, fraction: float) -> bool:
    """Deterministic, platform-independent coin: is this raw image (or group) in the held-out fraction?"""
    h = int.from_bytes(hashlib.sha1(ident.encode()).digest()[:8], "big")
    return h / 2**64 < fraction


def holdout_group(raw_path: str, source: str | None = None) -> str:
    """What a holdout by recording keeps whole for a raw image: the bag or video it is a frame of (labels'
    `source`), else the KITTI drive its path names, else its folder."""
    if source:
        return source
    drive = _DRIVE.search(raw_path)
    return drive.group(0) if drive else posixpath.dirname(raw_path.replace("\\", "/"))


def held_out(groups: set[str], fraction: float) -> frozenset[str]:
    """The groups a holdout keeps for validation: `fraction` of them (at least one, never all), chosen by hash so
    that the choice does not depend on their order or count elsewhere."""
    ranked = sorted(groups, key=lambda r: hashlib.sha1(r.encode()).digest())
    return frozenset(ranked[:min(len(ranked) - 1, max(1, round(fraction * len(ranked))))])


def is_held(ident: str, source: str | None, by: str, held: frozenset[str] | None, fraction: float) -> bool:
    """Whether a raw image (its raw_path, or key) is on the validation side of a holdout by `by`: its group among
    `held` when known, else a hash coin per group (by recording) or per image."""
    if by == "recording":
        ident = holdout_group(ident, source)
        if held is not None:
            return ident in held
    return in_holdout(ident, fraction)


def holdout_unit(labels: Mapping[str, list] | None, split: str, val_by: str, val_fraction: float
                 ) -> tuple[str, frozenset[str] | None]:
    """--val-by and, by recording, the held-out groups of `split`'s rows (None: a hash coin per group, without
    labels); errors name the option.

    A split recorded in one folder (e.g. synthetic frames, each its own scene) is held out by image: a holdout
    by recording would have to put all of it on one side.
    """
    if not 0 < val_fraction < 1:
        raise TrainError(f"--val-fraction must be in (0, 1), got {val_fraction}")
    if val_by not in HOLDOUT_UNITS:
        raise TrainError(f"--val-by must be one of {', '.join(HOLDOUT_UNITS)}, got {val_by!r}")
    if val_by == "image" or labels is None:
        return val_by, None
    sources = labels.get("source") or [None] * len(labels["split"])
    rows = zip(labels["split"], labels["raw_path"], sources, strict=True)
    found = {holdout_group(str(r), o) for s, r, o in rows if s == split}
    if len(found) < 2:
        print(f"fit: split {split!r} is one recording ({next(iter(found), '?')!r}); holding out by image",
              file=sys.stderr)
        return "image", None
    return "recording", held_out(found, val_fraction)


def frame_sides(images: list[RawImage], split: str, val_split: str, val_fraction: float, val_by: str
                ) -> tuple[list[RawImage], list[RawImage]]:
    """(training frames, validation frames) of the online fit under the offline fit's rules: a named split, else
    whole recordings (KITTI drive, else folder) or single images held out by hash."""
    unsplit = all(i.split == "all" for i in images)  # --split-by none: every frame is the training split's
    train = [i for i in images if unsplit or i.split == split]
    if not train:
        found = ", ".join(sorted({i.split for i in images}))
        raise TrainError(f"--images: no frames of split {split!r} (found {found})")
    val_split = val_choice(val_split, any(i.split == "val" for i in images) and not unsplit)
    if val_split == "none":
        return train, []
    if val_split != "holdout":
        val = [i for i in images if i.split == val_split]
        if not val:
            raise TrainError(f"--val-split {val_split!r}: no frames of that split")
        return train, val
    labels = {"split": [split] * len(train), "raw_path": [i.name for i in train]}
    by, held = holdout_unit(labels, split, val_by, val_fraction)
    sides = [is_held(i.name, None, by, held, val_fraction) for i in train]
    return ([i for i, v in zip(train, sides, strict=True) if not v],
            [i for i, v in zip(train, sides, strict=True) if v])
