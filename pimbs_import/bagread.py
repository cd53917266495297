"""Time series of the mapped quantities, read from a ROS 1 ``.bag`` or a ROS 2 bag directory.

``rosbags`` reads both (sqlite3 and mcap storage) without a ROS installation. Each topic is
deserialized once however many quantities it carries (the convention's two message types by
``fastdecode``, others by ``rosbags``); element names are resolved once per distinct name list
(a JointState publisher sends the same list every time).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pimbs_import.fastdecode import FastDecoder
from pimbs_import.mapping import Channel, LogMapping, MappingError, normalize_type


class LogError(ValueError):
    """The log cannot be imported as mapped; the message names the log, topic and fix."""


@dataclass
class Series:
    """One quantity: times (ns, increasing) and values (T, K) in the robot's order (NaN
    where a message did not carry that element)."""

    time: np.ndarray
    values: np.ndarray


def read_series(log: Path, mapping: LogMapping, joints: Sequence[str], muscles: Sequence[str],
                progress: Callable[[int, int], None] | None = None) -> dict[str, Series]:
    """Series for every mapped quantity (absent optional ones left out)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    paths = [log]
    try:
        reader = AnyReader(paths, default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except (AnyReaderError, FileNotFoundError) as exc:
        raise LogError(f"{log}: cannot open as a ROS 1 .bag or a ROS 2 bag directory ({exc}); "
                       "give a .bag file or the directory holding metadata.yaml") from exc
    try:
        topics = reader.topics
        wanted = {q: ch for q, ch in mapping.channels.items() if ch is not None}
        for q, ch in list(wanted.items()):
            if ch.topic not in topics:
                if q == "temperature":
                    del wanted[q]
                    continue
                have = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(topics.items()))
                raise LogError(f"{log}: no topic {ch.topic} for {q} (the log has: {have}); "
                               f"record it, or map {q} to another topic with --map")
            found = normalize_type(topics[ch.topic].msgtype or "")
            if found != ch.type:
                raise LogError(f"{log}: topic {ch.topic} ({q}) has type {found}, expected "
                               f"{ch.type}; map {q} with --map (type, field) to read it")
        by_topic: dict[str, list[tuple[str, Channel]]] = {}
        for q, ch in wanted.items():
            by_topic.setdefault(ch.topic, []).append((q, ch))
        conns = [c for c in reader.connections if c.topic in by_topic]
        total = sum(topics[t].msgcount for t in by_topic)
        names = {"theta": joints, "length": muscles, "tension": muscles, "temperature": muscles}
        pickers = {q: _Picker(log, q, ch, names[q]) for q, ch in wanted.items()}
        times: dict[str, list[np.ndarray]] = {q: [] for q in wanted}
        rows: dict[str, list[np.ndarray]] = {q: [] for q in wanted}
        fast = FastDecoder()
        # the convention's types are kept raw and decoded in bulk after the pass
        raw_topics = {t for t in by_topic if fast.supports(normalize_type(
            topics[t].msgtype or ""))}
        kept: dict[str, tuple[list[int], list[bytes]]] = {t: ([], []) for t in raw_topics}
        for n, (conn, stamp, raw) in enumerate(reader.messages(connections=conns)):
            if conn.topic in kept:
                kept[conn.topic][0].append(stamp)
                kept[conn.topic][1].append(bytes(raw))
            else:
                msg = reader.deserialize(raw, conn.msgtype)
                t = stamp if mapping.clock == "log" else _header_time(log, conn.topic, msg)
                for q, _ in by_topic[conn.topic]:
                    value = pickers[q].pick(msg)
                    if value is not None:
                        times[q].append(np.array([t]))
                        rows[q].append(value[None])
            if progress is not None and n % 20000 == 0:
                progress(n, total)
        for topic, (stamps, raws) in kept.items():
            stamps_ns = np.asarray(stamps, dtype=np.int64)
            msgtype = normalize_type(topics[topic].msgtype or "")
            for batch in fast.decode_many(raws, msgtype, reader.is2):
                if mapping.clock == "log":
                    t = stamps_ns[batch.rows]
                elif batch.stamp_ns is None:
                    raise LogError(f"{log}: topic {topic} has no header; use 'clock: log' in "
                                   "the mapping")
                else:
                    t = batch.stamp_ns
                for q, _ in by_topic[topic]:
                    values = pickers[q].pick_many(batch.name, batch.fields)
                    if values is not None:
                        times[q].append(t)
                        rows[q].append(values)
        if progress is not None:
            progress(total, total)
    finally:
        reader.close()
    out = {}
    for q in wanted:
        if pickers[q].missing():
            raise LogError(pickers[q].missing_message(
                pickers[q].missing(), f"'{wanted[q].names}' ({sorted(pickers[q].seen)})"))
        if not rows[q]:
            raise LogError(f"{log}: topic {wanted[q].topic} has no message for {q}")
        t = np.concatenate(times[q])
        order = np.argsort(t, kind="stable")
        out[q] = Series(time=t[order],
                        values=pickers[q].scaled(np.concatenate(rows[q])[order]))
    return out


def _header_time(log: Path, topic: str, msg: object) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        raise LogError(f"{log}: topic {topic} has no header; use 'clock: log' in the mapping")
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class _Picker:
    """Extracts one quantity's values, in the robot's order, from messages of one topic.

    A message may carry only some of the robot's elements (two publishers on one
    ``/joint_states``, one per limb); the others read NaN and ``align`` interpolates each
    element from the messages that carry it. Only an element no message carries is an error.
    """

    def __init__(self, log: Path, quantity: str, ch: Channel, wanted: Sequence[str]) -> None:
        self.log, self.quantity, self.ch, self.wanted = log, quantity, ch, list(wanted)
        self._cache: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, int]] = {}
        self._last: tuple[tuple[str, ...] | None, tuple] = (None, ())
        self.seen: set[str] = set()  # element names met (after rename)
        if ch.names is None:
            order = [ch.rename.get(n, n) for n in (ch.order or self.wanted)]
            self._fixed = self._match(order)
            missing = [n for n in self.wanted if n not in order]
            if missing:
                raise LogError(self.missing_message(missing, f"order {order}"))

    def _match(self, names: list[str]) -> tuple[np.ndarray, np.ndarray, int]:
        """(source index, robot index, message length needed) of the robot's elements."""
        self.seen.update(names)
        pairs = [(names.index(n), k) for k, n in enumerate(self.wanted) if n in names]
        src = np.array([p[0] for p in pairs], dtype=np.int64)
        dst = np.array([p[1] for p in pairs], dtype=np.int64)
        return src, dst, (int(src.max()) + 1 if len(src) else 0)

    def missing_message(self, missing: list[str], where: str) -> str:
        return (f"{self.log}: topic {self.ch.topic} ({self.quantity}) has no element(s) "
                f"{missing} of the robot in its {where}; the robot has {self.wanted}. Map "
                f"log names to the robot's with --map ({self.quantity}: rename: "
                "{log_name: robot_name})")

    def missing(self) -> list[str]:
        return [n for n in self.wanted if n not in self.seen]

    def pick(self, msg: object) -> np.ndarray | None:
        """Values of one message (rosbags-deserialized), or None if it has none."""
        try:
            data = np.asarray(getattr(msg, self.ch.field), dtype=np.float64)
        except AttributeError:
            raise self._no_field() from None
        names = None if self.ch.names is None else getattr(msg, self.ch.names)
        out = self.pick_many(names, {self.ch.field: data[None]}, check=False)
        return None if out is None else out[0]

    def pick_many(self, names: tuple[str, ...] | None, fields: dict[str, np.ndarray],
                  check: bool = True) -> np.ndarray | None:
        """(n, K) values of messages of one layout (NaN for elements they do not carry), or
        None if they carry none of the robot's."""
        if self.ch.field not in fields:
            raise self._no_field()
        if check and self.ch.names not in (None, "name"):
            raise LogError(f"{self.log}: topic {self.ch.topic}: names field "
                           f"'{self.ch.names}' is not in this message type; use 'name'")
        data = fields[self.ch.field]
        src, dst, needed = self._index_of(None if self.ch.names is None else names)
        if not len(src) or data.shape[1] < needed:
            return None  # e.g. a JointState without efforts, or another limb's publisher
        if len(dst) == len(self.wanted):
            return data[:, src]
        out = np.full((len(data), len(self.wanted)), np.nan)
        out[:, dst] = data[:, src]
        return out

    def _index_of(self, names) -> tuple[np.ndarray, np.ndarray, int]:
        if names is None:
            return self._fixed
        key, found = self._last
        if key is not names:
            key = tuple(names)
            found = self._cache.get(key)
            if found is None:
                found = self._cache[key] = self._match([self.ch.rename.get(n, n)
                                                        for n in key])
            self._last = (names, found)
        return found

    def _no_field(self) -> LogError:
        return LogError(f"{self.log}: topic {self.ch.topic} has no field '{self.ch.field}' "
                        f"for {self.quantity}; set field in --map")

    def scaled(self, values: np.ndarray) -> np.ndarray:
        scale, offset = (np.asarray(v, dtype=np.float64) for v in (self.ch.scale,
                                                                   self.ch.offset))
        for name, v in (("scale", scale), ("offset", offset)):
            if v.ndim and v.shape != (values.shape[1],):
                raise MappingError(f"{self.quantity}.{name}: {v.size} values for "
                                   f"{values.shape[1]} elements; give one per element in the "
                                   "robot's order, or a single number")
        return values * scale + offset
