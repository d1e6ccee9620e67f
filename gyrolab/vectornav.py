"""VectorNav's serial protocol (VN-100 User Manual UM001 rev 2.22, firmware 2.1.0.0): ASCII
register commands and the binary output packet, shared by the ``vectornav`` driver and the
simulated VN-100 (docs/instruments.md, "VectorNav VN-100").

* **ASCII commands** (UM001 §3.8, §5.1): ``$VNRRG,<id>*CS`` reads a register,
  ``$VNWRG,<id>,<values>*CS`` writes one (the reply echoes the command with the register's
  values), ``$VNERR,<code>*CS`` answers an error. ``CS`` is the 8-bit XOR of every byte
  between ``$`` and ``*`` as two hex digits (§3.8.2) or the 16-bit CRC as four (§3.8.3);
  lines end in CR LF.
* **Binary output packet** (§4.3): sync byte ``0xFA``, the groups byte, one u16 field mask
  per active group, the payload (the selected fields, group by group in bit order, little
  endian), and the CRC16-CCITT of everything after the sync byte (polynomial 0x1021,
  initial value 0, big endian), so that the CRC over the packet including it is 0 (§4.3.6;
  the manual's example packet ``FA 01 08 00 … 92 88`` checks). Field sizes: §4.3.6's
  ``groupLen`` table.

The packet this project asks for (:data:`GROUPS`, :data:`FIELDS`): group 1 (Common)
``TimeStartup`` (u64, ns since start-up), group 3 (IMU) ``UncompAccel`` (3 float, m/s²),
``UncompGyro`` (3 float, rad/s: the factory calibration only, no Kalman-filter bias,
§4.6.4) and ``Temp`` (float, °C, §4.6.5).
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass
from functools import reduce

SYNC = 0xFA
IMU_RATE_HZ = 800.0  # RateDivisor divides the IMU rate, nominally 800 Hz (§5.2.11)
# Registers (§5.2, §6.2): read-only identity, and those the driver sets for a run.
REG_MODEL, REG_SERIAL, REG_FIRMWARE = 1, 3, 4
REG_ASYNC_OUTPUT = 6  # ADOR: 0 = no asynchronous ASCII output
REG_REFERENCE_FRAME = 26  # 3×3 rotation of the body frame (recorded, never changed)
REG_BINARY_OUTPUTS = (75, 76, 77)  # Binary Output Registers 1-3
REG_GYRO_COMPENSATION = 84  # C (3×3) · (G − B): the user's compensation
GYRO_COMPENSATION_NONE = "1,0,0,0,1,0,0,0,1,0,0,0"  # identity, no bias (factory default)

GROUPS = 0x05  # group 1 (Common) and group 3 (IMU)
FIELDS = (0x0001, 0x001C)  # TimeStartup; UncompAccel, UncompGyro, Temp
PAYLOAD = struct.Struct("<Q3f3ff")  # time ns, accel m/s², gyro rad/s, temperature °C
HEADER = bytes([SYNC, GROUPS]) + struct.pack("<2H", *FIELDS)
PACKET_LEN = len(HEADER) + PAYLOAD.size + 2

ERRORS = {  # $VNERR codes (UM004 §4.5, the same in UM001)
    1: "hard fault",
    2: "serial buffer overflow",
    3: "invalid checksum",
    4: "invalid command",
    5: "not enough parameters",
    6: "too many parameters",
    7: "invalid parameter",
    8: "invalid register",
    9: "unauthorized access",
    10: "watchdog reset",
    11: "output buffer overflow",
    12: "insufficient baud rate",
}


def checksum8(body: bytes) -> int:
    """The 8-bit XOR checksum of the bytes between ``$`` and ``*`` (UM001 §3.8.2)."""
    return reduce(lambda a, b: a ^ b, body, 0)


def crc16(data: bytes) -> int:
    """CRC16-CCITT, polynomial 0x1021, initial value 0 (UM001 §3.8.3; XModem's CRC)."""
    return binascii.crc_hqx(data, 0)


def line(body: str) -> bytes:
    """``$<body>*CS\\r\\n`` with the 8-bit checksum."""
    b = body.encode("ascii")
    return b"$" + b + b"*%02X\r\n" % checksum8(b)


def parse_line(raw: bytes) -> list[str] | None:
    """The comma-separated fields of a ``$VN…*CS`` line (without CR LF), or None when it is
    not one or its checksum (8-bit or 16-bit) does not match."""
    if not raw.startswith(b"$") or b"*" not in raw:
        return None
    body, _, cs = raw[1:].rpartition(b"*")
    try:
        value = int(cs, 16)
    except ValueError:
        return None
    ok = (len(cs) == 2 and value == checksum8(body)) or (len(cs) == 4 and value == crc16(body))
    if not ok:
        return None
    try:
        return body.decode("ascii").split(",")
    except UnicodeDecodeError:
        return None


def binary_output(async_mode: int, divisor: int) -> str:
    """The values of a Binary Output Register for this project's packet (§5.2.11):
    ``AsyncMode,RateDivisor,OutputGroup,OutputField…`` (group and fields in hex, as the
    manual's example ``$VNWRG,75,1,16,15,0001,000C,0014`` writes them)."""
    return f"{async_mode},{divisor},{GROUPS:02X}," + ",".join(f"{f:04X}" for f in FIELDS)


@dataclass(frozen=True)
class Sample:
    """One binary packet's content."""

    time_ns: int
    accel_m_s2: tuple[float, float, float]
    gyro_rad_s: tuple[float, float, float]
    temperature_c: float


def packet(s: Sample) -> bytes:
    """The binary packet of ``s`` (module doc)."""
    body = HEADER[1:] + PAYLOAD.pack(s.time_ns, *s.accel_m_s2, *s.gyro_rad_s, s.temperature_c)
    return bytes([SYNC]) + body + struct.pack(">H", crc16(body))


@dataclass
class DecoderStats:
    packets_ok: int = 0
    crc_errors: int = 0
    other_packets: int = 0  # intact, but another group/field selection
    bytes_skipped: int = 0
    lines: int = 0
    bad_lines: int = 0


class Decoder:
    """Splits the byte stream into this project's binary packets and ASCII lines.

    A packet counts only with its header as :data:`HEADER` and a zero CRC over it; a line
    only with a valid checksum (:func:`parse_line`). Anything else is skipped a byte at a
    time until the next sync byte or ``$`` (a packet with another field selection — the
    user's own output before the driver set its own — is skipped whole when its CRC
    checks out: its length is unknown here, so it is found by the CRC)."""

    MAX_LINE = 256  # the VN-100's command buffer (UM004 §4.5 error 2)

    def __init__(self) -> None:
        self.buf = bytearray()
        self.stats = DecoderStats()

    def feed(self, data: bytes) -> tuple[list[Sample], list[list[str]]]:
        """Packets and lines complete in what arrived so far (in order of arrival)."""
        self.buf += data
        samples: list[Sample] = []
        lines: list[list[str]] = []
        buf = self.buf
        i = 0
        st = self.stats
        while i < len(buf):
            b = buf[i]
            if b == SYNC:
                if len(buf) - i < PACKET_LEN:
                    if bytes(buf[i : i + len(HEADER)]) == HEADER[: len(buf) - i]:
                        break  # a packet of ours still arriving
                    other = self._other_packet(buf, i)
                    if other is None:
                        break
                    if other:
                        i += other
                        continue
                elif bytes(buf[i : i + len(HEADER)]) == HEADER:
                    if crc16(bytes(buf[i + 1 : i + PACKET_LEN])) == 0:
                        t, *rest = PAYLOAD.unpack_from(buf, i + len(HEADER))
                        samples.append(
                            Sample(int(t), tuple(rest[0:3]), tuple(rest[3:6]), float(rest[6]))
                        )
                        st.packets_ok += 1
                        i += PACKET_LEN
                        continue
                    st.crc_errors += 1
                else:
                    other = self._other_packet(buf, i)
                    if other:
                        i += other
                        continue
            elif b == ord("$"):
                end = _line_end(buf, i, self.MAX_LINE)
                if end is None:
                    break  # a line still arriving
                if end >= 0:
                    fields = parse_line(bytes(buf[i:end]))
                    if fields is not None:
                        lines.append(fields)
                        st.lines += 1
                        i = end + 2
                        continue
                    st.bad_lines += 1
            st.bytes_skipped += 1
            i += 1
        del buf[:i]
        return samples, lines

    def _other_packet(self, buf: bytearray, i: int) -> int | None:
        """Length of an intact packet of another selection at ``i`` (0: none; None: maybe,
        wait for more bytes). Its header says its groups and fields; its length follows
        from the manual's field sizes for the IMU and Common groups; other groups are
        not decoded (0)."""
        n = len(buf) - i
        if n < 2:
            return None
        groups = buf[i + 1]
        if groups & 0x80 or groups == 0:
            return 0
        active = [g for g in range(7) if groups >> g & 1]
        if n < 2 + 2 * len(active):
            return None
        masks = struct.unpack_from(f"<{len(active)}H", buf, i + 2)
        size = 0
        for g, m in zip(active, masks, strict=True):
            table = GROUP_FIELD_SIZES.get(g)
            if table is None or m & 0x8000:
                return 0
            size += sum(table[k] for k in range(15) if m >> k & 1)
        total = 2 + 2 * len(active) + size + 2
        if n < total:
            return None if total <= 600 else 0
        if crc16(bytes(buf[i + 1 : i + total])) != 0:
            return 0
        self.stats.other_packets += 1
        return total


def _line_end(buf: bytearray, i: int, limit: int) -> int | None:
    """Where the ASCII line starting at ``i`` ends (its CR), −1 when it is no line (a byte
    that is not printable ASCII before CR LF, or longer than ``limit``), None while it may
    still be arriving."""
    for j in range(i + 1, min(len(buf), i + limit)):
        c = buf[j]
        if c == 0x0D:
            if j + 1 == len(buf):
                return None
            return j if buf[j + 1] == 0x0A else -1
        if not 0x20 <= c <= 0x7E:
            return -1
    return None if len(buf) < i + limit else -1


# Payload bytes of each field (bit 0..14) of groups 1 (Common) and 3 (IMU): UM001 §4.3.6,
# ``groupLen`` (0-based group index).
GROUP_FIELD_SIZES = {
    0: (8, 8, 8, 12, 16, 12, 24, 12, 12, 24, 20, 28, 2, 4, 8),
    2: (2, 12, 12, 12, 4, 4, 16, 12, 12, 12, 12, 2, 40, 0, 0),
}
