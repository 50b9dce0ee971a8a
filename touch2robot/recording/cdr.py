"""CDR (XCDR1, little-endian) encoding and fast batch decoding of the recording
message types in ``schemas.messages``.

Decoding is vectorised: all messages of a topic are stacked into one byte matrix when
their layouts are identical (same strings, same array lengths: the normal case for a
rig), and every numeric field is sliced out as a column block at once. Messages whose
layouts differ fall back to the per-message decoder, which is also the reference
implementation the fast path is checked against.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE


class CdrError(ValueError):
    """A message whose bytes do not decode as its declared type."""


# ----------------------------------------------------------------------------- encoding
class _Writer:
    def __init__(self) -> None:
        self.buf = bytearray(ENCAPSULATION)

    def align(self, n: int) -> None:
        pad = (-(len(self.buf) - 4)) % n
        self.buf += b"\x00" * pad

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", v)

    def i32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<i", v)

    def string(self, s: str) -> None:
        b = s.encode() + b"\x00"
        self.u32(len(b))
        self.buf += b

    def header(self, stamp_ns: int, frame_id: str) -> None:
        self.i32(stamp_ns // 1_000_000_000)
        self.u32(stamp_ns % 1_000_000_000)
        self.string(frame_id)

    def f64(self, v: float) -> None:
        self.align(8)
        self.buf += struct.pack("<d", v)

    def array(self, values: np.ndarray, dtype: str) -> None:
        arr = np.ascontiguousarray(values, dtype=dtype)
        self.u32(arr.size)
        if arr.size:
            self.align(arr.itemsize)
            self.buf += arr.tobytes()


def encode_tactile(stamp_ns: int, frame_id: str, values: np.ndarray) -> bytes:
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.array(values, "<f4")
    return bytes(w.buf)


def encode_reference_time(stamp_ns: int, frame_id: str, reference_time: float) -> bytes:
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.f64(reference_time)
    return bytes(w.buf)


def encode_joint_state(
    stamp_ns: int,
    frame_id: str,
    names: tuple[str, ...],
    position: np.ndarray,
    velocity: np.ndarray | None = None,
    effort: np.ndarray | None = None,
) -> bytes:
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.u32(len(names))
    for n in names:
        w.string(n)
    w.array(position, "<f8")
    w.array(np.zeros(0) if velocity is None else velocity, "<f8")
    w.array(np.zeros(0) if effort is None else effort, "<f8")
    return bytes(w.buf)


def _pose(w: _Writer, pos: np.ndarray, quat_wxyz: np.ndarray) -> None:
    w.align(8)
    # geometry_msgs order: position x y z, orientation x y z w
    w.buf += np.array([pos[0], pos[1], pos[2], quat_wxyz[1], quat_wxyz[2], quat_wxyz[3], quat_wxyz[0]], "<f8").tobytes()


def encode_pose_stamped(stamp_ns: int, frame_id: str, pos: np.ndarray, quat_wxyz: np.ndarray) -> bytes:
    w = _Writer()
    w.header(stamp_ns, frame_id)
    _pose(w, pos, quat_wxyz)
    return bytes(w.buf)


def encode_tf(stamp_ns: int, parent: str, child: str, pos: np.ndarray, quat_wxyz: np.ndarray) -> bytes:
    """A tf2_msgs/TFMessage of one transform, ``child`` in ``parent``."""
    w = _Writer()
    w.u32(1)
    w.header(stamp_ns, parent)
    w.string(child)
    _pose(w, pos, quat_wxyz)  # Transform (Vector3, Quaternion) has Pose's layout
    return bytes(w.buf)


def encode_string(text: str) -> bytes:
    """A std_msgs/String."""
    w = _Writer()
    w.string(text)
    return bytes(w.buf)


def encode_pose_array(stamp_ns: int, frame_id: str, positions: np.ndarray) -> bytes:
    """Keypoints as a PoseArray: positions (K, 3), identity orientations."""
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.u32(len(positions))
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    for p in positions:
        _pose(w, p, ident)
    return bytes(w.buf)


# ----------------------------------------------------------------------------- decoding
@dataclass
class _Span:
    name: str
    offset: int
    dtype: str
    count: int


@dataclass
class _Layout:
    """Where each numeric field of one message lies; everything else is 'structure'."""

    size: int
    spans: list[_Span] = field(default_factory=list)


class _Reader:
    def __init__(self, data: bytes) -> None:
        if data[:2] != ENCAPSULATION[:2]:
            raise CdrError(f"unsupported CDR encapsulation {data[:4]!r} (expected little-endian CDR)")
        self.data = data
        self.pos = 4
        self.layout = _Layout(size=len(data))

    def align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def _take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise CdrError(f"message ends after {len(self.data)} bytes, needs {self.pos + n}")
        b = self.data[self.pos : self.pos + n]
        self.pos += n
        return b

    def u32(self) -> int:
        self.align(4)
        return struct.unpack("<I", self._take(4))[0]

    def string(self) -> str:
        n = self.u32()
        raw = self._take(n)
        if n == 0 or raw[-1:] != b"\x00":
            raise CdrError("string is not NUL-terminated")
        return raw[:-1].decode("utf-8", errors="replace")

    def numeric(self, name: str, dtype: str, count: int) -> np.ndarray:
        itemsize = np.dtype(dtype).itemsize
        if count:
            self.align(itemsize)
        self.layout.spans.append(_Span(name, self.pos, dtype, count))
        return np.frombuffer(self._take(itemsize * count), dtype=dtype)

    def header(self) -> str:
        self.numeric("stamp_sec", "<i4", 1)
        self.numeric("stamp_nanosec", "<u4", 1)
        return self.string()

    def seq(self, name: str, dtype: str) -> np.ndarray:
        return self.numeric(name, dtype, self.u32())


def _decode_one(msg_type: str, data: bytes) -> tuple[dict, _Layout]:
    r = _Reader(data)
    out: dict = {"frame_id": r.header()}
    if msg_type == "touch2robot_msgs/msg/TactileArray":
        out["values"] = r.seq("values", "<f4")
    elif msg_type == "touch2robot_msgs/msg/ReferenceTime":
        out["reference_time"] = r.numeric("reference_time", "<f8", 1)
    elif msg_type == "sensor_msgs/msg/JointState":
        out["name"] = tuple(r.string() for _ in range(r.u32()))
        for f in ("position", "velocity", "effort"):
            out[f] = r.seq(f, "<f8")
    elif msg_type == "geometry_msgs/msg/PoseStamped":
        out["pose"] = r.numeric("pose", "<f8", 7)
    elif msg_type == "geometry_msgs/msg/PoseArray":
        n = r.u32()
        out["poses"] = r.numeric("poses", "<f8", 7 * n) if n else np.zeros(0)
    else:
        raise CdrError(f"no decoder for message type {msg_type!r}")
    if r.pos != len(data) and any(data[r.pos :]):
        raise CdrError(f"{len(data) - r.pos} unexpected trailing bytes")
    sec = struct.unpack_from("<i", data, r.layout.spans[0].offset)[0]
    nsec = struct.unpack_from("<I", data, r.layout.spans[1].offset)[0]
    out["stamp_ns"] = sec * 1_000_000_000 + nsec
    return out, r.layout


def decode(msg_type: str, data: bytes) -> dict:
    """Decode one message (reference implementation). Fields: frame_id, stamp_ns and the
    type's payload (values / reference_time / name+position+velocity+effort / pose / poses;
    poses as flat float64 [x, y, z, qx, qy, qz, qw] per pose)."""
    return _decode_one(msg_type, data)[0]


@dataclass(frozen=True)
class Batch:
    """Decoded messages of one topic: stamps (n,) int64 ns, numeric fields as (n, k) arrays,
    and the per-message strings that must be constant across the topic."""

    stamp_ns: np.ndarray
    fields: dict[str, np.ndarray]
    frame_ids: tuple[str, ...]
    names: tuple[str, ...] | None


def decode_batch(msg_type: str, messages: list[bytes]) -> Batch:
    """Decode all messages of one topic at once. Raises CdrError naming the message index
    when a message cannot be decoded or array lengths differ between messages."""
    if not messages:
        raise CdrError("no messages")
    try:
        first, layout = _decode_one(msg_type, messages[0])
    except CdrError as e:
        raise CdrError(f"message 0: {e}") from None
    n = len(messages)
    sizes = np.fromiter(map(len, messages), dtype=np.int64, count=n)
    if (sizes == layout.size).all():
        mat = np.frombuffer(b"".join(messages), dtype=np.uint8).reshape(n, layout.size)
        structural = np.ones(layout.size, dtype=bool)
        for s in layout.spans:
            structural[s.offset : s.offset + np.dtype(s.dtype).itemsize * s.count] = False
        # identical strings and array lengths <=> identical structure bytes
        same = (mat[:, structural] == mat[0, structural]).all(axis=1)
        if same.all():
            cols = {}
            for s in layout.spans:
                width = np.dtype(s.dtype).itemsize * s.count
                cols[s.name] = (
                    np.ascontiguousarray(mat[:, s.offset : s.offset + width]).view(s.dtype).reshape(n, s.count)
                )
            stamp = cols.pop("stamp_sec")[:, 0].astype(np.int64) * 1_000_000_000 + cols.pop("stamp_nanosec")[:, 0]
            return Batch(stamp, cols, (first["frame_id"],), first.get("name"))
    return _decode_slow(msg_type, messages)


def _decode_slow(msg_type: str, messages: list[bytes]) -> Batch:
    decoded = []
    for i, m in enumerate(messages):
        try:
            decoded.append(decode(msg_type, m))
        except CdrError as e:
            raise CdrError(f"message {i}: {e}") from None
    keys = [k for k, v in decoded[0].items() if isinstance(v, np.ndarray)]
    cols = {}
    for k in keys:
        lengths = {len(d[k]) for d in decoded}
        if len(lengths) > 1:
            bad = next(i for i, d in enumerate(decoded) if len(d[k]) != len(decoded[0][k]))
            raise CdrError(
                f"field {k!r} has length {len(decoded[bad][k])} in message {bad}, {len(decoded[0][k])} in message 0"
            )
        cols[k] = np.stack([d[k] for d in decoded])
    names = {d.get("name") for d in decoded}
    if len(names) > 1:
        raise CdrError("joint names change between messages")
    return Batch(
        np.array([d["stamp_ns"] for d in decoded], dtype=np.int64),
        cols,
        tuple(sorted({d["frame_id"] for d in decoded})),
        decoded[0].get("name"),
    )
