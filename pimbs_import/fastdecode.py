"""Direct decoding of the two message types the import convention uses, for hour-long logs.

``rosbags`` deserializes any message type, at about 6.5 µs of CPU per JointState here, plus
the Python work per message object; an hour of ``/joint_states`` at 200 Hz plus
``/muscle_states`` at 100 Hz is a million messages. The
convention's types (``sensor_msgs/JointState``, ``std_msgs/Float64MultiArray``) have fixed,
simple layouts, so they are read here (ROS 1 serialization and ROS 2 CDR, either byte order):
``decode_many`` finds the layout of one message (where the name list, the counts and the
float arrays sit), checks in one vectorised comparison which messages of the same size share
it, and reads their arrays as columns of one byte matrix. Messages that share no layout are
decoded one by one. Any other type goes through ``rosbags``. ``tests/test_import.py`` checks
both paths agree with ``rosbags``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

_SUPPORTED = ("sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray")


class DamagedMessage(ValueError):
    """A message's bytes do not parse as its type, or parse to fewer bytes than it has (ROS 1
    and CDR carry no checksum; a length that does not add up is the one sign of damage)."""

    def __init__(self, index: int, reason: str) -> None:
        super().__init__(f"message {index + 1}: {reason}")
        self.index = index


@dataclass
class _Stamp:
    sec: int
    nanosec: int


@dataclass
class _Header:
    stamp: _Stamp
    frame_id: str


@dataclass
class JointStateMsg:
    header: _Header
    name: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


@dataclass
class Float64ArrayMsg:
    data: np.ndarray


class _Cursor:
    """Reads a ROS 1 buffer (packed, little endian) or a CDR buffer (aligned, either
    endianness; alignment counted from the end of the 4-byte encapsulation header)."""

    def __init__(self, raw: bytes | memoryview, cdr: bool) -> None:
        self.raw, self.cdr = raw, cdr
        if cdr:
            little = raw[1] == 1
            self.base, self.pos = 4, 4
        else:
            little, self.base, self.pos = True, 0, 0
        self.little = little
        self.u32 = struct.Struct("<I" if little else ">I")
        self.f8 = np.dtype("<f8" if little else ">f8")

    def check_end(self) -> None:
        """The whole buffer was read (CDR: up to 3 bytes of trailing alignment, as
        ``rosbags`` allows)."""
        left = len(self.raw) - self.pos
        if left < 0 or left > (3 if self.cdr else 0):
            raise ValueError(f"{len(self.raw)} bytes, of which the type's fields take "
                             f"{self.pos}")

    def align(self, n: int) -> None:
        if self.cdr:
            self.pos += -(self.pos - self.base) % n

    def uint32(self) -> int:
        self.align(4)
        value = self.u32.unpack_from(self.raw, self.pos)[0]
        self.pos += 4
        return value

    def string(self) -> str:
        n = self.uint32()
        text = bytes(self.raw[self.pos:self.pos + n])
        self.pos += n
        return (text[:-1] if self.cdr and text.endswith(b"\0") else text).decode()

    def skip_string(self) -> None:
        n = self.uint32()  # (not `self.pos += self.uint32()`: that adds to the old pos)
        self.pos += n

    def float64s(self) -> np.ndarray:
        n = self.uint32()
        if n:
            self.align(8)
        values = np.frombuffer(self.raw, self.f8, n, self.pos)
        self.pos += 8 * n
        return values


@dataclass
class Batch:
    """Messages of one layout: ``rows`` index the caller's list of raw messages."""

    rows: np.ndarray  # (n,)
    name: tuple[str, ...]  # JointState's names (() for arrays)
    fields: dict[str, np.ndarray]  # field -> (n, k) float64
    stamp_ns: np.ndarray | None  # (n,) header stamps (None without a header)


@dataclass
class _Layout:
    fixed: np.ndarray  # byte positions that must be equal for messages of this layout
    arrays: dict[str, tuple[int, int]]  # field -> (byte offset, count)
    stamp: int | None  # byte offset of header.stamp (sec, then nanosec), None: no header
    name: tuple[str, ...]
    little: bool


class FastDecoder:
    """Decodes JointState and Float64MultiArray messages; None for anything else."""

    def __init__(self) -> None:
        self._names: dict[bytes, tuple[str, ...]] = {}
        self._last: tuple[bytes, tuple[str, ...]] = (b"\xff", ())  # matches no buffer

    @staticmethod
    def supports(msgtype: str) -> bool:
        return msgtype in _SUPPORTED

    def decode(self, raw: bytes | memoryview, msgtype: str, cdr: bool) -> object | None:
        if msgtype not in _SUPPORTED:
            return None
        c = _Cursor(raw, cdr)
        msg = self._joint_state(c) if msgtype == _SUPPORTED[0] else self._float_array(c)
        c.check_end()
        return msg

    def _joint_state(self, c: _Cursor) -> JointStateMsg:
        if not c.cdr:
            c.uint32()  # seq
        sec, nanosec = c.uint32(), c.uint32()
        header = _Header(_Stamp(sec, nanosec), c.string())
        start = c.pos
        key, names = self._last
        # The name list encodes its own length: bytes equal to a decoded list's are that list.
        if c.raw[start:start + len(key)] == key:
            c.pos = start + len(key)
        else:
            for _ in range(c.uint32()):
                c.skip_string()
            key = bytes(c.raw[start:c.pos])
            names = self._names.get(key)
            if names is None:  # a new list of names: decode it (once)
                end, c.pos = c.pos, start
                names = tuple(c.string() for _ in range(c.uint32()))
                c.pos = end
                self._names[key] = names
            self._last = (key, names)
        return JointStateMsg(header, names, c.float64s(), c.float64s(), c.float64s())

    def decode_many(self, raws: list[bytes], msgtype: str, cdr: bool,
                    max_layouts: int = 32) -> list[Batch]:
        """All of ``raws`` (one message type), as batches of equal layout."""
        lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=len(raws))
        pending = np.arange(len(raws))
        batches: list[Batch] = []
        while len(pending) and len(batches) < max_layouts:
            first = int(pending[0])
            layout = _guarded(first, self._layout, raws[first], msgtype, cdr)
            same = pending[lengths[pending] == lengths[first]]
            block = np.frombuffer(b"".join([raws[i] for i in same]), np.uint8).reshape(
                len(same), lengths[first])
            ok = (block[:, layout.fixed] == block[0, layout.fixed]).all(axis=1)
            batches.append(_batch(same[ok], block[ok], layout))
            pending = np.setdiff1d(pending, same[ok], assume_unique=True)
        for i in pending:  # layouts beyond max_layouts: one message at a time
            msg = _guarded(int(i), self.decode, raws[i], msgtype, cdr)
            batches.append(_single(int(i), msg))
        return batches

    def _layout(self, raw: bytes, msgtype: str, cdr: bool) -> _Layout:
        c = _Cursor(raw, cdr)
        fixed: list[range] = []
        stamp = None
        if msgtype == _SUPPORTED[0]:
            if not cdr:
                c.uint32()  # seq: varies
            c.align(4)
            stamp = c.pos
            c.pos += 8
            c.align(4)
            begin = c.pos
            c.string()
            c.align(4)
            names = tuple(c.string() for _ in range(c.uint32()))
            fixed.append(range(begin, c.pos))
            fields = ("position", "velocity", "effort")
        else:
            begin = c.pos
            self._float_array_layout(c)
            fixed.append(range(begin, c.pos))
            names, fields = (), ("data",)
        arrays = {}
        for name in fields:
            c.align(4)
            fixed.append(range(c.pos, c.pos + 4))
            values = c.float64s()
            arrays[name] = (c.pos - 8 * len(values), len(values))
        c.check_end()
        return _Layout(fixed=np.fromiter((i for r in fixed for i in r), dtype=np.int64),
                       arrays=arrays, stamp=stamp, name=names, little=c.little)

    @staticmethod
    def _float_array_layout(c: _Cursor) -> None:
        """Moves past layout.dim and layout.data_offset (up to data's count)."""
        for _ in range(c.uint32()):
            c.skip_string()
            c.uint32()
            c.uint32()
        c.uint32()

    @staticmethod
    def _float_array(c: _Cursor) -> Float64ArrayMsg:
        for _ in range(c.uint32()):  # layout.dim: label, size, stride
            c.skip_string()
            c.uint32()
            c.uint32()
        c.uint32()  # layout.data_offset
        return Float64ArrayMsg(c.float64s())


def _guarded(index: int, decode, *args):
    """``decode(*args)``, its parse errors (a count past the end, bytes that are no text, a
    length that does not add up) raised as :class:`DamagedMessage` of message ``index``."""
    try:
        return decode(*args)
    except (struct.error, ValueError, IndexError) as exc:
        raise DamagedMessage(index, str(exc) or exc.__class__.__name__) from None


def _batch(rows: np.ndarray, block: np.ndarray, layout: _Layout) -> Batch:
    f8, u4 = ("<f8", "<u4") if layout.little else (">f8", ">u4")
    fields = {name: np.ascontiguousarray(block[:, off:off + 8 * k]).view(f8).astype(
        np.float64) for name, (off, k) in layout.arrays.items()}
    stamp = None
    if layout.stamp is not None:
        sec_nsec = np.ascontiguousarray(block[:, layout.stamp:layout.stamp + 8]).view(u4)
        stamp = sec_nsec[:, 0].astype(np.int64) * 1_000_000_000 + sec_nsec[:, 1]
    return Batch(rows=rows, name=layout.name, fields=fields, stamp_ns=stamp)


def _single(i: int, msg: object) -> Batch:
    if isinstance(msg, JointStateMsg):
        fields = {k: getattr(msg, k)[None] for k in ("position", "velocity", "effort")}
        stamp = np.array([msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec])
        return Batch(rows=np.array([i]), name=msg.name, fields=fields, stamp_ns=stamp)
    return Batch(rows=np.array([i]), name=(), fields={"data": msg.data[None]}, stamp_ns=None)
