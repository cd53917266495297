"""Write a file so that a reader sees the old one or the complete new one, never a part.

A full disk, a permission error or ``kill -9`` in the middle of writing a recording, a model
description, a JSON report or a figure must not leave a truncated file under the real name:
a truncated PNG or JSON looks like a result. Everything is written to a temporary file next
to the target, flushed to disk, then renamed over it (atomic on POSIX); on failure the
temporary file is removed and the error names the file that could not be written.
"""

from __future__ import annotations

import contextlib
import errno as errno_codes
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO


class AtomicWriteError(OSError):
    """Writing ``path`` failed; whatever was at ``path`` before is unchanged."""

    def __init__(self, code: int, message: str, reason: str) -> None:
        super().__init__(code, message)
        self.reason = reason  # the system's words: "No space left on device"


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[BinaryIO]:
    """Binary file handle whose content replaces ``path`` only when the block succeeds.

    The parent directory must exist (no directory is created on the caller's behalf). An
    ``OSError`` inside the block or while committing becomes :class:`AtomicWriteError`
    naming ``path``; other exceptions propagate unchanged and also leave ``path`` untouched.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and not isinstance(exc, AtomicWriteError):
            reason = exc.strerror or (os.strerror(exc.errno) if exc.errno else str(exc))
            code = exc.errno or errno_codes.EIO
            raise AtomicWriteError(
                code, f"could not write {path}: {reason}; {path.name} was left as it was "
                      "(free disk space or check permissions, then run again)", reason) from exc
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """``path.write_bytes(data)``, atomically (see :func:`atomic_file`)."""
    with atomic_file(path) as fh:
        fh.write(data)
    return Path(path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """``path.write_text(text)`` in UTF-8, atomically (see :func:`atomic_file`)."""
    return write_bytes_atomic(path, text.encode("utf-8"))
