"""The valve-board wire protocol: framed ASCII lines, encoded and decoded without any I/O.

Both ends use this module (the host in ``hardware.valves``, the emulated board in
``hardware.emulator``), so they cannot drift apart; ``hardware/PROTOCOL.md`` is the
specification a firmware author implements. A frame is one line::

    $<seq> <VERB> [arg ...]*<crc>\\n      e.g.  $7 SET 1250 0 0 0 0 0 0*7E7F\\n

``crc`` is CRC-16/CCITT-FALSE of the bytes between ``$`` and ``*`` in four upper-case hex
digits. Pressures travel as integer millibar so no float formatting reaches the wire.
"""

from __future__ import annotations

import binascii
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

PROTOCOL_VERSION = 1
DEFAULT_BAUD = 921600  # over a UART; 115200 spends 10.5 ms per SET round trip on the wire (benchmarks/valves.py)
MAX_FRAME_BYTES = 128  # including "$", "*", the checksum and the line terminator
SEQ_MODULO = 65536  # sequence numbers count 0..65535 and wrap
MAX_MBAR = 65535  # widest set-point a SET argument may carry
MAX_COUNT = 65535  # a board's counters stop here

# Host -> board commands. A retry re-sends the identical frame; the board carries it out only once.
HOST_VERBS = ("VER", "STAT", "HB", "SET", "VENT", "ESTOP", "CLR")
# Board -> host replies.
ACK, NAK = "ACK", "NAK"
# NAK reasons: the frame was unreadable, its checksum failed, the verb is unknown,
# the arguments are wrong, or a SET was refused because the e-stop is latched.
NAK_REASONS = ("FRAME", "CRC", "VERB", "ARGS", "ESTOP")

_VERB = re.compile(rb"[A-Z]{1,8}")
_ARG = re.compile(rb"[!-#%-)+-~]{1,40}")  # printable ASCII without space, "$" or "*"
_SEQ = re.compile(rb"0|[1-9][0-9]{0,4}")
_CRC = re.compile(rb"[0-9A-F]{4}")
_COUNT = re.compile(rb"0|[1-9][0-9]{0,4}")


class ProtocolError(ValueError):
    """A line is not a valid frame.

    Attributes:
        reason: the NAK reason a board answers with ("FRAME" or "CRC").
        seq: the frame's sequence number when it could be read and trusted, else None.
    """

    def __init__(self, reason: str, message: str, seq: int | None = None) -> None:
        super().__init__(message)
        self.reason = reason
        self.seq = seq


@dataclass(frozen=True)
class Frame:
    """One decoded frame: ``seq`` (None only in a board's NAK to an unreadable frame), verb, args."""

    seq: int | None
    verb: str
    args: tuple[str, ...] = ()


def checksum(body: bytes) -> str:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of ``body`` as four upper-case hex digits."""
    return f"{binascii.crc_hqx(body, 0xFFFF):04X}"


def encode(seq: int | None, verb: str, *args: object) -> bytes:
    """Build one frame, terminator included.

    Args:
        seq: 0..65535, or None for "?" (only a board replying to an unreadable frame uses it).
        verb: upper-case letters, e.g. "SET".
        args: rendered with ``str``; each must be printable ASCII without spaces, "$" or "*".

    Raises:
        ValueError: a bad sequence number, verb or argument, or a frame longer than
            ``MAX_FRAME_BYTES``.
    """
    if seq is None:
        seq_text = b"?"
    elif isinstance(seq, int) and not isinstance(seq, bool) and 0 <= seq < SEQ_MODULO:
        seq_text = str(seq).encode()
    else:
        raise ValueError(f"seq: expected an integer in [0, {SEQ_MODULO}), got {seq!r}")
    verb_bytes = verb.encode("ascii", "replace")
    if not _VERB.fullmatch(verb_bytes):
        raise ValueError(f"verb: expected 1-8 upper-case letters, got {verb!r}")
    parts = [seq_text, verb_bytes]
    for arg in args:
        text = str(arg).encode("ascii", "replace")
        if not _ARG.fullmatch(text):
            raise ValueError(f"argument {arg!r}: expected 1-40 printable ASCII characters without space, '$' or '*'")
        parts.append(text)
    body = b" ".join(parts)
    frame = b"$" + body + b"*" + checksum(body).encode() + b"\n"
    if len(frame) > MAX_FRAME_BYTES:
        raise ValueError(f"frame of {len(frame)} bytes exceeds the {MAX_FRAME_BYTES}-byte limit")
    return frame


def decode(line: bytes) -> Frame:
    """Parse one line (with or without its ``\\n`` or ``\\r\\n``) into a frame.

    Raises:
        ProtocolError: ``reason`` "FRAME" for anything malformed, "CRC" for a checksum
            mismatch; neither carries a trusted sequence number.
    """
    if line.endswith(b"\n"):
        line = line[:-1]
    if line.endswith(b"\r"):
        line = line[:-1]
    if len(line) + 1 > MAX_FRAME_BYTES:
        raise ProtocolError("FRAME", f"frame longer than {MAX_FRAME_BYTES} bytes")
    if not line.startswith(b"$"):
        raise ProtocolError("FRAME", "frame does not start with '$'")
    body, star, crc = line[1:].rpartition(b"*")
    if not star or not _CRC.fullmatch(crc):
        raise ProtocolError("FRAME", "frame does not end with '*' and four upper-case hex digits")
    if checksum(body).encode() != crc:
        raise ProtocolError("CRC", f"checksum {crc.decode()} does not match {checksum(body)}")
    parts = body.split(b" ")
    if len(parts) < 2 or not all(parts):
        raise ProtocolError("FRAME", "expected '<seq> <VERB> [args]' separated by single spaces")
    seq_text, verb, args = parts[0], parts[1], parts[2:]
    if seq_text == b"?":
        seq = None
    elif _SEQ.fullmatch(seq_text) and int(seq_text) < SEQ_MODULO:
        seq = int(seq_text)
    else:
        raise ProtocolError("FRAME", f"sequence number {seq_text[:8]!r} is not an integer in [0, {SEQ_MODULO})")
    if not _VERB.fullmatch(verb):
        raise ProtocolError("FRAME", f"verb {verb[:8]!r} is not 1-8 upper-case letters", seq)
    for arg in args:
        if not _ARG.fullmatch(arg):
            raise ProtocolError("FRAME", "an argument is not printable ASCII without '$' or '*'", seq)
    return Frame(seq, verb.decode(), tuple(a.decode() for a in args))


class LineSplitter:
    """Cut a byte stream into lines, whatever the read sizes; drop overlong lines.

    A line longer than ``MAX_FRAME_BYTES`` is returned as the single sentinel
    ``LineSplitter.OVERFLOW`` once its terminator arrives, so the receiver can NAK it.
    """

    OVERFLOW = b"\x00overflow"

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._overflowed = False

    def feed(self, data: bytes) -> list[bytes]:
        """Add received bytes; return the non-empty lines they complete (terminators stripped)."""
        *complete, rest = data.split(b"\n")
        lines = []
        for chunk in complete:
            self._append(chunk)
            lines.append(self.OVERFLOW if self._overflowed else bytes(self._buffer).rstrip(b"\r"))
            self._buffer.clear()
            self._overflowed = False
        self._append(rest)
        return [line for line in lines if line]

    def _append(self, data: bytes) -> None:
        if self._overflowed:
            return
        self._buffer += data
        if len(self._buffer) >= MAX_FRAME_BYTES:
            self._buffer.clear()
            self._overflowed = True


# --- fixed-point pressures ----------------------------------------------------------------


def bar_to_mbar(pressure_bar: float, limit_bar: float) -> int:
    """Round a validated pressure to integer millibar, never above ``limit_bar``.

    Rounding could lift a value up to 0.5 mbar over a limit that is not a whole number of
    millibar, so the result is capped at ``floor(limit_bar * 1000)`` (computed in floating
    point, so at worst 1 mbar conservative, never above).

    Raises:
        ValueError: the pressure is NaN, negative or above the limit.
    """
    if not (0.0 <= pressure_bar <= limit_bar):  # also rejects NaN
        raise ValueError(f"pressure {pressure_bar!r} bar is outside [0, {limit_bar}] bar")
    return min(round(pressure_bar * 1000.0), math.floor(limit_bar * 1000.0))


# --- reply payloads -----------------------------------------------------------------------


@dataclass(frozen=True)
class BoardStatus:
    """What every ACK except VER's reports.

    Attributes:
        estop: the e-stop is latched (all channels vented, SET refused until CLR).
        watchdog_tripped: the watchdog vented the valves since the previous reply.
        setpoints_mbar: the set-point applied on each board channel, millibar.
        unreadable_frames: lines the board could not read since it started (answered with a
            ``?`` NAK; stops at 65535), or None when the board does not report it (the optional
            ``bad=`` field): a count that keeps rising means a noisy cable.
    """

    estop: bool
    watchdog_tripped: bool
    setpoints_mbar: tuple[int, ...]
    unreadable_frames: int | None = None

    def fields(self) -> tuple[str, ...]:
        """The ACK arguments carrying this status."""
        fields = (f"estop={int(self.estop)}", f"wdt={int(self.watchdog_tripped)}",
                  "mbar=" + ",".join(str(v) for v in self.setpoints_mbar))
        return fields if self.unreadable_frames is None else (*fields, f"bad={self.unreadable_frames}")

    @classmethod
    def parse(cls, args: Sequence[str]) -> BoardStatus:
        """Read the status from ACK arguments. Raises ``ProtocolError`` (reason "ARGS")."""
        values = _key_values(args, ("estop", "wdt", "mbar"))
        try:
            bad = values.get("bad")
            if bad is not None and not (_COUNT.fullmatch(bad.encode()) and int(bad) <= MAX_COUNT):
                raise ValueError(f"bad={bad!r} is not a count 0..{MAX_COUNT}")
            return cls(_flag(values["estop"]), _flag(values["wdt"]),
                       tuple(int(v) for v in values["mbar"].split(",")), None if bad is None else int(bad))
        except ValueError as e:
            raise ProtocolError("ARGS", f"bad status fields {' '.join(args)!r}: {e}") from e


@dataclass(frozen=True)
class BoardVersion:
    """The board's answer to VER.

    Attributes:
        protocol: protocol version the firmware speaks.
        firmware: firmware name and version, e.g. "softarm-emu/0.1.0".
        channels: number of valve channels (the length of SET's argument list).
        max_mbar: the board's own set-point limit, millibar.
        lsb_umbar: one DAC step, micro-bar (the resolution set-points are rounded to).
        watchdog_ms: the board vents when no valid frame arrived for this long.
    """

    protocol: int
    firmware: str
    channels: int
    max_mbar: int
    lsb_umbar: int
    watchdog_ms: int

    def fields(self) -> tuple[str, ...]:
        return (f"proto={self.protocol}", f"fw={self.firmware}", f"ch={self.channels}",
                f"max_mbar={self.max_mbar}", f"lsb_umbar={self.lsb_umbar}", f"wdt_ms={self.watchdog_ms}")

    @classmethod
    def parse(cls, args: Sequence[str]) -> BoardVersion:
        """Read the version from ACK arguments. Raises ``ProtocolError`` (reason "ARGS")."""
        values = _key_values(args, ("proto", "fw", "ch", "max_mbar", "lsb_umbar", "wdt_ms"))
        try:
            return cls(int(values["proto"]), values["fw"], int(values["ch"]), int(values["max_mbar"]),
                       int(values["lsb_umbar"]), int(values["wdt_ms"]))
        except ValueError as e:
            raise ProtocolError("ARGS", f"bad version fields {' '.join(args)!r}: {e}") from e


def _key_values(args: Iterable[str], required: Sequence[str]) -> dict[str, str]:
    values = dict(arg.partition("=")[::2] for arg in args)
    missing = [key for key in required if key not in values]
    if missing:
        raise ProtocolError("ARGS", f"reply lacks field(s) {', '.join(missing)}")
    return values


def _flag(text: str) -> bool:
    if text not in ("0", "1"):
        raise ValueError(f"expected 0 or 1, got {text!r}")
    return text == "1"
