"""One recording, one writer: an OS lock held for as long as a run writes a recording.

Two `pimbs collect --resume --out same.parquet` started at once would each append their own
rows and rewrite the file, so each would silently drop the other's samples. The writer
therefore holds ``flock`` on ``FILE.lock`` beside the recording for its whole run. The
kernel releases a ``flock`` when its process ends however it ends (``kill -9``, a power cut
ends everything anyway), so a lock can never go stale; the file left behind after a crash
is only a name, and the next writer takes it over.

The lock is on a separate file because the recording itself is replaced by an atomic rename
after every row: a lock on its old inode would not stop a writer opening the new one.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import fcntl
import os
import socket
from collections.abc import Iterator
from pathlib import Path

LOCK_SUFFIX = ".lock"


class RecordingInUseError(RuntimeError):
    """Another live process is writing this recording."""

    def __init__(self, path: Path, holder: str) -> None:
        self.path, self.holder = path, holder
        super().__init__(f"{path} is being written by another process ({holder}); wait for "
                         "it to finish or stop it (Ctrl-C), then rerun, or choose another "
                         "--out")


def lock_path(path: Path) -> Path:
    """``FILE.lock`` beside the recording ``FILE``."""
    return path.with_name(path.name + LOCK_SUFFIX)


@contextlib.contextmanager
def writer_lock(path: Path) -> Iterator[Path]:
    """Hold the writer lock of recording ``path`` for the ``with`` block.

    Raises :class:`RecordingInUseError` (naming the holder's pid when it wrote it) at once if
    another process holds it; nothing on disk is changed then. The lock file is removed when
    the block ends normally or by an exception.
    """
    lock = lock_path(Path(path))
    fd = _acquire(Path(path), lock)
    try:
        with contextlib.suppress(OSError):  # who holds it is a courtesy; a full disk must
            os.ftruncate(fd, 0)              # not stop the run, the lock itself is held
            os.write(fd, (f"pid {os.getpid()} on {socket.gethostname()}, since "
                          f"{dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M:%S} UTC\n").encode())
        yield lock
    finally:
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()  # while still held: a waiting writer then sees a new file
        os.close(fd)


def _acquire(path: Path, lock: Path) -> int:
    """An open, ``flock``-ed descriptor of ``lock`` that is still the file at that name."""
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot create the lock file {lock} that keeps a second "
                          f"writer off {path} ({exc.strerror}); write the recording into a "
                          "directory you can write to") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _holder(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                raise RecordingInUseError(path, holder) from None
            raise
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False  # the previous holder removed it between our open and our lock
        if same:
            return fd
        os.close(fd)


def _holder(fd: int) -> str:
    """What the holding process wrote into the lock file (its pid), or that it is unknown."""
    with contextlib.suppress(OSError):
        text = os.pread(fd, 200, 0).decode("utf-8", "replace").strip()
        if text:
            return text.splitlines()[0]
    return "pid unknown"
