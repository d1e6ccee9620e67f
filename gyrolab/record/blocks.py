"""The Protobuf codec of the batched gyro streams (``GyroAdcBlock``, ``GyroRateBlock``).

The payloads are encoded and decoded here by hand (packed fixed-width fields are raw
little-endian arrays), which keeps a 47 M-sample run at numpy speed; the
FileDescriptorSet stored as the schema (:func:`gyrolab.record.format.file_descriptor_set`)
lets generic readers decode them too.
"""

from __future__ import annotations

import struct

import numpy as np

from gyrolab.record.format import MAX_AXES


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _read_varint(mv: memoryview, i: int) -> tuple[int, int]:
    """The varint starting at byte ``i`` of ``mv`` and the index after it (inverse of
    :func:`_varint`)."""
    v = shift = 0
    while True:
        if i >= len(mv):
            raise ValueError("a varint runs past the block")
        b = mv[i]
        i += 1
        v |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return v, i


def encode_block(
    t0: float, period: float, first_index: int, values: np.ndarray, kind: str
) -> bytes:
    """Protobuf wire bytes of a block; ``kind`` is ``"adc"`` (int32) or ``"rate"`` (float32).

    ``values`` is ``(n,)`` for one axis or ``(n, axes)`` for 2–3 axes (stored interleaved,
    sample-major, with ``axes`` in field 5). A single-axis block omits field 5, so its bytes
    are those of the format before axis counts existed."""
    dtype = "<i4" if kind == "adc" else "<f4"
    v = np.asarray(values)
    axes = 1 if v.ndim == 1 else int(v.shape[1])
    if v.ndim > 2 or not 1 <= axes <= MAX_AXES:
        raise ValueError(f"a block holds (n,) or (n, 1..{MAX_AXES}) values, not {v.shape}")
    payload = np.ascontiguousarray(v, dtype=dtype).tobytes()
    tail = (b"\x28", _varint(axes)) if axes > 1 else ()
    return b"".join(
        (
            b"\x09",
            struct.pack("<d", t0),
            b"\x11",
            struct.pack("<d", period),
            b"\x18",
            _varint(int(first_index)),
            b"\x22",
            _varint(len(payload)),
            payload,
            *tail,
        )
    )


def decode_block(data: bytes, kind: str) -> tuple[float, float, int, np.ndarray]:
    """Inverse of :func:`encode_block`; accepts any valid field order. The values come back
    ``(n,)`` for a single-axis block, ``(n, axes)`` for a multi-axis one. Bytes that are not
    such a block (a field past the end, a wire type it does not use) are a ValueError,
    never a block made of what was there."""
    t0 = period = 0.0
    first = 0
    axes = 1
    arr: np.ndarray = np.empty(0, dtype="<i4" if kind == "adc" else "<f4")
    mv = memoryview(data)
    i, n = 0, len(data)
    while i < n:
        key, i = _read_varint(mv, i)
        fno, wt = key >> 3, key & 7
        if wt == 1:
            if i + 8 > n:
                raise ValueError(f"field {fno} runs past the block")
            (val,) = struct.unpack_from("<d", mv, i)
            i += 8
            if fno == 1:
                t0 = val
            elif fno == 2:
                period = val
        elif wt == 0:
            v, i = _read_varint(mv, i)
            if fno == 3:
                first = v
            elif fno == 5:
                axes = max(1, v)
        elif wt == 2:
            ln, i = _read_varint(mv, i)
            if i + ln > n:
                raise ValueError(f"field {fno} runs {i + ln - n} bytes past the block")
            if fno == 4:
                arr = np.frombuffer(mv[i : i + ln], dtype=arr.dtype)
            i += ln
        elif wt == 5:
            if i + 4 > n:
                raise ValueError(f"field {fno} runs past the block")
            i += 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wt}")
    if axes > 1:
        if arr.size % axes:
            raise ValueError(f"{arr.size} values do not split into {axes} axes")
        arr = arr.reshape(-1, axes)
    return t0, period, first, arr
