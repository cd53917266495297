"""Time series of the mapped quantities, read from a ROS 1 ``.bag`` or a ROS 2 bag directory.

``rosbags`` reads both (sqlite3 and mcap storage) without a ROS installation. Each topic is
deserialized once however many quantities it carries (the convention's two message types by
``fastdecode``, others by ``rosbags``); element names are resolved once per distinct name list
(a JointState publisher sends the same list every time).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pimbs_import.bagopen import (
    LogError,
    ensure_types,
    open_log,
    reader_errors,
    short_text,
    topic_list,
)
from pimbs_import.fastdecode import DamagedMessage, FastDecoder
from pimbs_import.mapping import Channel, LogMapping, MappingError, normalize_type

__all__ = ["LogError", "Series", "read_series"]


@dataclass
class Series:
    """One quantity: times (ns, increasing) and values (T, K) in the robot's order (NaN
    where a message did not carry that element).

    ``backwards`` counts messages whose time is earlier than the message before on their
    topic (possible with ``clock: header``); ``nonfinite`` counts NaN or infinite values of
    elements the messages carried. Both are left for :mod:`pimbs_import.checks` to refuse or
    flag."""

    time: np.ndarray
    values: np.ndarray
    topic: str = ""
    backwards: int = 0
    nonfinite: int = 0


def read_series(log: Path, mapping: LogMapping, joints: Sequence[str], muscles: Sequence[str],
                progress: Callable[[int, int], None] | None = None,
                msg_dirs: Sequence[Path] = ()) -> dict[str, Series]:
    """Series for every mapped quantity (absent optional ones left out)."""
    reader = open_log(log, msg_dirs)
    try:
        topics = reader.topics
        wanted = {q: ch for q, ch in mapping.channels.items() if ch is not None}
        for q, ch in list(wanted.items()):
            if ch.topic not in topics:
                if q == "temperature":
                    del wanted[q]
                    continue
                listed = topic_list(topics, prefer=ch.type)
                raise LogError(f"{log}: no topic {ch.topic} for {q} (the log has "
                               f"{len(topics)} topic(s): {listed}); record it, or map {q} to "
                               "another topic with --map (see all topics with pimbs import "
                               "LOG --list-topics)")
            found = normalize_type(topics[ch.topic].msgtype or "")
            if found != ch.type:
                raise LogError(f"{log}: topic {ch.topic} ({q}) has type {found}, expected "
                               f"{ch.type}; map {q} with --map (type, field) to read it")
        by_topic: dict[str, list[tuple[str, Channel]]] = {}
        for q, ch in wanted.items():
            by_topic.setdefault(ch.topic, []).append((q, ch))
        fast = FastDecoder()
        # the convention's types are kept raw and decoded in bulk after the pass
        raw_topics = {t for t in by_topic if fast.supports(normalize_type(
            topics[t].msgtype or ""))}
        ensure_types(log, reader, {t: topics[t].msgtype for t in by_topic
                                   if t not in raw_topics})
        conns = [c for c in reader.connections if c.topic in by_topic]
        total = sum(topics[t].msgcount for t in by_topic)
        names = {"theta": joints, "length": muscles, "tension": muscles, "temperature": muscles}
        pickers = {q: _Picker(log, q, ch, names[q]) for q, ch in wanted.items()}
        # per quantity: (message index on its topic, time, values) blocks
        blocks: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {
            q: [] for q in wanted}
        kept: dict[str, tuple[list[int], list[bytes]]] = {t: ([], []) for t in raw_topics}
        counts = dict.fromkeys(by_topic, 0)
        n = 0
        try:
            for n, (conn, stamp, raw) in enumerate(reader.messages(connections=conns)):
                index = counts[conn.topic]
                counts[conn.topic] += 1
                if conn.topic in kept:
                    kept[conn.topic][0].append(stamp)
                    kept[conn.topic][1].append(bytes(raw))
                else:
                    msg = reader.deserialize(raw, conn.msgtype)
                    t = stamp if mapping.clock == "log" else _header_time(log, conn.topic, msg)
                    for q, _ in by_topic[conn.topic]:
                        value = pickers[q].pick(msg)
                        if value is not None:
                            blocks[q].append((np.array([index]), np.array([t]), value[None]))
                if progress is not None and n % 20000 == 0:
                    progress(n, total)
        except (*reader_errors(), struct.error) as exc:
            raise LogError(f"{log}: damaged after {n} readable message(s) of {total} on the "
                           f"mapped topics ({short_text(exc)}); nothing was imported. Copy the bag "
                           "again from the recording machine, or cut it to its readable part "
                           "(rosbag filter / ros2 bag convert) and import that") from None
        _check_counts(log, counts, {t: topics[t].msgcount for t in by_topic})
        for topic, (stamps, raws) in kept.items():
            stamps_ns = np.asarray(stamps, dtype=np.int64)
            msgtype = normalize_type(topics[topic].msgtype or "")
            try:
                batches = list(fast.decode_many(raws, msgtype, reader.is2))
            except DamagedMessage as exc:
                raise LogError(f"{log}: topic {topic}: a {msgtype} message is damaged "
                               f"({short_text(exc)}); nothing was imported. Copy the bag again "
                               "from the recording machine") from None
            for batch in batches:
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
                        blocks[q].append((batch.rows, t, values))
        if progress is not None:
            progress(total, total)
    finally:
        reader.close()
    out = {}
    for q in wanted:
        picker = pickers[q]
        if picker.missing():
            raise LogError(picker.missing_message(
                picker.missing(), f"'{wanted[q].names}' ({sorted(picker.seen)})"))
        if not blocks[q]:
            raise LogError(picker.nothing_message())
        index = np.concatenate([b[0] for b in blocks[q]])
        t = np.concatenate([b[1] for b in blocks[q]])
        values = picker.scaled(np.concatenate([b[2] for b in blocks[q]]))
        in_order = np.argsort(index, kind="stable")
        backwards = int(np.count_nonzero(np.diff(t[in_order]) < 0))
        order = np.argsort(t, kind="stable")
        out[q] = Series(time=t[order], values=values[order], topic=wanted[q].topic,
                        backwards=backwards, nonfinite=picker.nonfinite)
    unused = {q: pickers[q].unused_renames() for q in wanted}
    unused = {q: keys for q, keys in unused.items() if keys}
    if unused:
        raise LogError(f"{log}: --map rename key(s) that match no element name in the log: "
                       + "; ".join(f"{q} ({wanted[q].topic}): {keys}"
                                   for q, keys in unused.items())
                       + "; correct or remove them (the log's names: "
                       + "; ".join(f"{q}: {sorted(pickers[q].raw_seen)[:12]}" for q in unused)
                       + ")")
    return out


def _check_counts(log: Path, read: dict[str, int], listed: dict[str, int]) -> None:
    """Every message the bag's index lists was read: a damaged ROS 2 .mcap chunk can end the
    reader's pass early without an error, losing the rest of the log silently."""
    short = {t: (read[t], n) for t, n in listed.items() if read[t] < n}
    if short:
        topic, (got, n) = next(iter(sorted(short.items())))
        raise LogError(f"{log}: damaged or cut short: read only {got} of the {n} message(s) "
                       f"its index lists on {topic}"
                       + (f" (and {len(short) - 1} more topic(s))" if len(short) > 1 else "")
                       + "; nothing was imported. Copy the bag again from the recording "
                       "machine, or cut it to its readable part (rosbag filter / ros2 bag "
                       "convert) and import that")


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
        self.raw_seen: set[str] = set()  # element names met (as in the log)
        self.short: tuple[int, int] | None = None  # (values found, values needed)
        self.nonfinite = 0  # NaN/inf values among the robot's elements the messages carried
        if ch.names is None:
            self.raw_seen.update(ch.order or self.wanted)
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

    def nothing_message(self) -> str:
        """Why no message gave this quantity a value."""
        where = f"{self.log}: topic {self.ch.topic} ({self.quantity})"
        if self.short is not None:
            have, need = self.short
            source = ("its 'order'" if self.ch.names is None
                      else f"the position of the robot's names in '{self.ch.names}'")
            return (f"{where}: messages too short: field '{self.ch.field}' has {have} "
                    f"value(s), {source} needs {need}; list only the array's elements in "
                    "'order' in --map, or map another field")
        return f"{where} has no message with values in field '{self.ch.field}'"

    def unused_renames(self) -> list[str]:
        """``rename`` keys that no element of the log is called."""
        return sorted(k for k in self.ch.rename if k not in self.raw_seen)

    def missing(self) -> list[str]:
        return [n for n in self.wanted if n not in self.seen]

    def pick(self, msg: object) -> np.ndarray | None:
        """Values of one message (rosbags-deserialized), or None if it has none."""
        try:
            data = np.atleast_1d(np.asarray(getattr(msg, self.ch.field), dtype=np.float64))
        except AttributeError:
            raise self._no_field() from None
        except (TypeError, ValueError):
            raise LogError(f"{self.log}: topic {self.ch.topic}: field '{self.ch.field}' "
                           f"({self.quantity}) does not hold numbers; map a numeric field "
                           "with --map") from None
        if data.ndim != 1:
            raise LogError(f"{self.log}: topic {self.ch.topic}: field '{self.ch.field}' "
                           f"({self.quantity}) is not a number or an array of numbers; map "
                           "another field with --map")
        names = None
        if self.ch.names is not None:
            try:
                names = getattr(msg, self.ch.names)
            except AttributeError:
                raise LogError(
                    f"{self.log}: topic {self.ch.topic} ({self.quantity}) has no field "
                    f"'{self.ch.names}' naming its values; for an array or a single value "
                    f"give their names in order in --map ({self.quantity}: order: [...])"
                ) from None
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
        if self.ch.names is not None and names is not None and not len(names) and data.shape[1]:
            raise LogError(f"{self.log}: topic {self.ch.topic} ({self.quantity}): messages "
                           f"carry values in '{self.ch.field}' but no names in "
                           f"'{self.ch.names}'; give the values' names in order in --map "
                           f"({self.quantity}: order: [...])")
        if not len(src):
            return None  # e.g. another limb's publisher
        if data.shape[1] < needed:
            if data.shape[1]:  # an empty field (a JointState without efforts) is not short
                self.short = (int(data.shape[1]), needed)
            return None
        self.nonfinite += int(np.count_nonzero(~np.isfinite(data[:, src])))
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
                self.raw_seen.update(key)
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
