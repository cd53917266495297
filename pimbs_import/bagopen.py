"""Opening a log for import: one line naming the file for anything that is not a readable bag,
the standard ROS message types registered where the bag lacks their definitions, and the
topic list kept short in messages.

A ROS 2 bag recorded before ROS Iron holds no message definitions; ``rosbags`` then needs the
types from elsewhere. The standard ones (``sensor_msgs``, ``std_msgs``, ...) ship with
``rosbags`` for every distribution and are registered here; a package's own type cannot be
guessed, so the message says which type is unknown and how to supply its ``.msg`` file.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

SHOWN_TOPICS = 5  # topics named in an error line; --list-topics shows them all


class LogError(ValueError):
    """The log cannot be imported as mapped; the message names the log, topic and fix."""


def reader_errors() -> tuple[type[BaseException], ...]:
    """Exceptions ``rosbags`` raises for a file that is not a bag or is damaged."""
    import sqlite3

    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error
    from rosbags.serde import SerdeError

    # OverflowError: a damaged .mcap record size sent to seek(); sqlite3 / apsw: a damaged
    # .db3; OSError (bz2, and the disk itself), RuntimeError (lz4) and the zstd modules'
    # errors: a damaged compressed chunk or message
    return (AnyReaderError, Ros1Error, Ros2Error, SerdeError, UnicodeDecodeError,
            OSError, EOFError, OverflowError, sqlite3.DatabaseError, RuntimeError,
            *_optional_errors())


def _optional_errors() -> tuple[type[BaseException], ...]:
    """Errors of the libraries ``rosbags`` reads with, which depend on its version and the
    Python version (apsw for sqlite3 storage; zstd from the standard library, its backport or
    zstandard)."""
    import importlib

    found = []
    for module, name in (("apsw", "Error"), ("compression.zstd", "ZstdError"),
                         ("backports.zstd", "ZstdError"), ("zstandard", "ZstdError")):
        try:
            found.append(getattr(importlib.import_module(module), name))
        except (ImportError, AttributeError):
            continue
    return tuple(found)


def open_log(log: Path, msg_dirs: Sequence[Path] = ()) -> Any:
    """An open ``AnyReader`` of ``log`` (a ROS 1 ``.bag`` or a ROS 2 bag directory)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([Path(log)], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except reader_errors() as exc:
        reason = not_a_bag_reason(Path(log))
        if reason is None:  # a bag by its first bytes (or metadata.yaml): damaged
            text = short_text(exc, drop=f"{log}/")
            raise LogError(f"{log}: a bag that cannot be opened ({text}); copy it again from "
                           "the recording machine (`rosbag reindex` / `ros2 bag reindex` "
                           "rebuild the index of a bag whose recorder was cut off)") from None
        raise LogError(f"{log}: not a readable ROS 1 .bag or ROS 2 bag directory ({reason}); "
                       "give a .bag file or the directory holding metadata.yaml") from None
    if msg_dirs:
        _register(reader.typestore, _types_from_msg_dirs(msg_dirs))
    return reader


ROS1_MAGIC = b"#ROSBAG V2.0\n"
# ROS 2 storage files, which rosbags also reads on their own (without metadata.yaml)
ROS2_MAGIC = (b"\x89MCAP", b"SQLite format 3\x00")
# first bytes of files people mistake for a bag, for the error line
KNOWN_MAGIC = {b"\x89PNG": "a PNG image", b"\xff\xd8\xff": "a JPEG image", b"%PDF": "a PDF",
               b"PK\x03\x04": "a zip archive", b"\x1f\x8b": "a gzip archive",
               b"\x28\xb5\x2f\xfd": "a zstd archive", b"PAR1": "a Parquet file"}


def not_a_bag_reason(log: Path) -> str | None:
    """What ``log`` is instead of a bag, in words, from its first bytes (None: it looks like
    a bag, so the reader's own reason is the better one). ``rosbags`` decodes a file's first
    line as text, which for a binary file gives a codec error that names no file format."""
    if log.is_dir():
        if not (log / "metadata.yaml").exists():
            return ("a folder without metadata.yaml; a ROS 2 bag directory holds one "
                    "(`ros2 bag reindex DIR` writes it for a bag that lost it)")
        return None
    try:
        with open(log, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        return f"cannot be read: {exc.strerror or exc}"
    if head.startswith(ROS1_MAGIC):
        return None if log.suffix == ".bag" else "a ROS 1 bag without the .bag suffix; rename it"
    if head.startswith(ROS2_MAGIC):
        return None
    kind = next((what for magic, what in KNOWN_MAGIC.items() if head.startswith(magic)), None)
    if not head:
        return "an empty file"
    return (f"{kind or 'a file'} that does not start with {ROS1_MAGIC.decode().strip()!r} as "
            "a ROS 1 bag does")


def ensure_types(log: Path, reader: Any, topics: Mapping[str, str]) -> None:
    """Make every ``{topic: msgtype}`` decodable: types the bag does not define are taken
    from the standard ROS types ``rosbags`` ships; anything else is one line saying which
    type is missing and how to supply it."""
    from rosbags.typesys import Stores, get_typestore

    store = reader.typestore
    missing = {t: m for t, m in topics.items() if m not in store.fielddefs}
    if not missing:
        return
    stores = ([Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.LATEST, Stores.ROS2_FOXY]
              if reader.is2 else [Stores.ROS1_NOETIC])
    for name in stores:
        standard = get_typestore(name).fielddefs
        _register(store, {k: v for k, v in standard.items() if k not in store.fielddefs})
        if all(m in store.fielddefs for m in missing.values()):
            return
    topic, msgtype = next((t, m) for t, m in missing.items() if m not in store.fielddefs)
    raise LogError(f"{log}: topic {topic} has type {msgtype}, which the bag does not define "
                   "(ROS 2 bags recorded before Iron hold no message definitions) and which is "
                   "not a standard ROS type; pass --msg-dir DIR, the folder of its package's "
                   f"msg/ files (DIR/{msgtype.split('/')[0]}/msg/{msgtype.split('/')[-1]}.msg)")


def _register(store: Any, types: Mapping[str, Any]) -> None:
    if types:
        store.register(dict(types))


def _types_from_msg_dirs(dirs: Sequence[Path]) -> dict[str, Any]:
    """Types of every ``PKG/msg/NAME.msg`` under the given folders."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for root in dirs:
        for path in sorted(Path(root).rglob("*.msg")):
            if path.parent.name != "msg":
                continue
            name = f"{path.parent.parent.name}/msg/{path.stem}"
            try:
                types.update(get_types_from_msg(path.read_text(), name))
            except Exception as exc:  # rosbags raises its parser's errors; name the file
                raise LogError(f"{path}: not a readable .msg definition ({short_text(exc)}); "
                               "fix or remove it") from None
    return types


def topic_list(topics: Mapping[str, Any], shown: int = SHOWN_TOPICS,
               prefer: str | None = None) -> str:
    """``/a (type), /b (type) and 92 more`` for an error line; topics of type ``prefer``
    (the type the mapping expects: the likely right topic) are named first."""
    from pimbs_import.mapping import normalize_type

    ordered = sorted(topics.items(),
                     key=lambda ti: (normalize_type(ti[1].msgtype or "") != prefer, ti[0]))
    items = [f"{t} ({i.msgtype})" for t, i in ordered]
    more = len(items) - shown
    return ", ".join(items[:shown]) + (f" and {more} more" if more > 0 else "")


def describe_topics(topics: Mapping[str, Any]) -> Iterable[str]:
    """One line per topic (name, type, message count) for ``--list-topics``."""
    width = max((len(t) for t in topics), default=0)
    for topic, info in sorted(topics.items()):
        yield f"{topic:<{width}}  {info.msgtype}  {info.msgcount} messages"


def short_text(exc: BaseException, drop: str = "") -> str:
    """The exception's text cut to 120 characters, without ``drop`` (a path the line names
    already)."""
    text = str(exc) or exc.__class__.__name__
    if drop:
        text = text.replace(drop, "")
    return text if len(text) <= 120 else text[:117] + "..."
