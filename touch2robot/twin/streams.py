"""Batch CDR encoding of the twin's recordings (their timing: ``touch2robot.recording.clock``).

Encoding: every message of a stream has the same layout (same frame id, joint names
and array lengths), so one message is encoded with ``touch2robot.recording.cdr`` as a template and
the rest are that template with the stamp and the numeric payload written in place, all messages of
a batch at once, as the rows of one byte matrix (what ``RecordingWriter.write_batch`` takes). The
per-message encoders cost more than the physics of a replay; this costs microseconds. Each row is
byte-identical to ``cdr.encode_*`` (tests/test_twin.py checks it).
"""

from __future__ import annotations

import functools

import numpy as np

from touch2robot.recording import cdr

_STAMP_AT = 4  # after the 4-byte encapsulation header: int32 sec, uint32 nanosec
_F64 = 8


# a message's layout depends on its strings and array lengths only: one template each, encoded once
@functools.cache
def _tactile_template(frame_id: str, width: int) -> bytes:
    return cdr.encode_tactile(0, frame_id, np.zeros(width))


@functools.cache
def _reference_time_template(frame_id: str) -> bytes:
    return cdr.encode_reference_time(0, frame_id, 0.0)


@functools.cache
def _joint_state_template(frame_id: str, names: tuple[str, ...], width: int, dynamics: bool) -> bytes:
    zeros = np.zeros(width)
    return cdr.encode_joint_state(0, frame_id, names, zeros, *((zeros, zeros) if dynamics else ()))


def _patch(template: bytes, stamp_ns: np.ndarray, fields: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """Copies of ``template`` as the rows of a uint8 matrix, one per stamp, with the header stamp and each
    (offset, (n, k) array) field written at its byte offset."""
    n = len(stamp_ns)
    buf = np.empty((n, len(template)), np.uint8)
    buf[:] = np.frombuffer(template, np.uint8)
    sec, nanosec = np.divmod(np.asarray(stamp_ns, np.int64), 1_000_000_000)
    buf[:, _STAMP_AT : _STAMP_AT + 4] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    buf[:, _STAMP_AT + 4 : _STAMP_AT + 8] = nanosec.astype("<u4").view(np.uint8).reshape(n, 4)
    for offset, values in fields:
        raw = np.ascontiguousarray(values).view(np.uint8).reshape(n, -1)
        buf[:, offset : offset + raw.shape[1]] = raw
    return buf


def encode_tactile(stamp_ns: np.ndarray, frame_id: str, values: np.ndarray) -> np.ndarray:
    """TactileArray messages: ``values`` (n, k) as float32, after the header and the array length."""
    values = np.asarray(values, "<f4")
    if not len(values):
        return np.empty((0, 0), np.uint8)
    template = _tactile_template(frame_id, values.shape[1])
    return _patch(template, stamp_ns, [(len(template) - values[0].nbytes, values)])


def encode_reference_time(stamp_ns: np.ndarray, frame_id: str, reference_time: np.ndarray) -> np.ndarray:
    """ReferenceTime messages: one float64 each, the last field."""
    values = np.asarray(reference_time, "<f8").reshape(-1, 1)
    if not len(values):
        return np.empty((0, 0), np.uint8)
    template = _reference_time_template(frame_id)
    return _patch(template, stamp_ns, [(len(template) - _F64, values)])


def encode_joint_state(
    stamp_ns: np.ndarray,
    frame_id: str,
    names: tuple[str, ...],
    position: np.ndarray,
    velocity: np.ndarray | None = None,
    effort: np.ndarray | None = None,
) -> np.ndarray:
    """JointState messages (n, len(names)) each. The three float64 arrays end the message; each after the
    first starts with its uint32 length, padded to 8 bytes (it follows an 8-byte-aligned array), and an empty
    array is its length alone."""
    position = np.asarray(position, "<f8")
    if not len(position):
        return np.empty((0, 0), np.uint8)
    width = position.shape[1] * _F64
    if velocity is None or effort is None:
        if velocity is not None or effort is not None:
            raise ValueError("velocity and effort go together (or neither)")
        template = _joint_state_template(frame_id, names, position.shape[1], False)
        return _patch(template, stamp_ns, [(len(template) - 8 - width, position)])
    template = _joint_state_template(frame_id, names, position.shape[1], True)
    end = len(template)
    return _patch(
        template,
        stamp_ns,
        [
            (end - 3 * width - 16, position),
            (end - 2 * width - 8, np.asarray(velocity, "<f8")),
            (end - width, np.asarray(effort, "<f8")),
        ],
    )
