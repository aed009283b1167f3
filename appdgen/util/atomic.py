"""Atomic file writes: readers see the old file or the whole new one, never a partial one."""
from __future__ import annotations

import os
import re
import secrets
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import BinaryIO

from appdgen.errors import AppdgenError

# `.<target name>.<8 hex digits>.tmp`: hidden, and never mistaken for a finished file by name patterns.
_TEMPORARY = re.compile(r"\.(?P<target>.+)\.[0-9a-f]{8}\.tmp")


def temporary_target(name: str) -> str | None:
    """The target's file name when `name` is one of atomic_write's temporaries, else None."""
    match = _TEMPORARY.fullmatch(name)
    return match.group("target") if match else None


@contextmanager
def atomic_stream(target: Path) -> Iterator[BinaryIO]:
    """A binary stream that appears at `target` only when the block ends without error (synced, renamed)."""
    temporary = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # umask applies, as for open()
        with os.fdopen(fd, "wb") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, target)
    finally:
        with suppress(OSError):
            temporary.unlink(missing_ok=True)


def atomic_write(target: Path, data: bytes) -> None:
    """Write bytes to a synced temporary file beside `target`, then rename it over `target` (OSError passes)."""
    with atomic_stream(target) as stream:
        stream.write(data)


def write_file(target: Path, data: bytes) -> None:
    """atomic_write after creating the parent folders; OS failures become one AppdgenError line naming the file."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(target, data)
    except OSError as exc:
        raise AppdgenError(f"{target}: cannot write: {exc.strerror or exc}") from None
