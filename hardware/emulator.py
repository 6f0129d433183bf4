"""An emulated valve-driver board on a pseudo-terminal, for tests and for trying the bench without hardware.

``BoardStateMachine`` is what the firmware must do (see ``hardware/PROTOCOL.md``): clamp to its
own limit, round to its DAC resolution, vent every channel when no valid frame arrived for
``watchdog_ms``, latch the e-stop until CLR, answer garbage with NAK instead of crashing (and
count it), and carry out a command the host re-sent only once.
``BoardEmulator`` serves that state machine on a pty from a thread, so ``SerialValveBank``
talks to it through a real serial device path::

    python -m hardware.emulator --link /tmp/softarm-valves   # then: port = "/tmp/softarm-valves"
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import math
import os
import select
import signal
import sys
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hardware.protocol import (
    ACK,
    MAX_COUNT,
    NAK,
    PROTOCOL_VERSION,
    BoardStatus,
    BoardVersion,
    Frame,
    LineSplitter,
    ProtocolError,
    decode,
    encode,
)


@dataclass(frozen=True)
class BoardEvent:
    """Something safety-relevant the board did: ``kind`` is "vent", "estop" or "clear"; ``cause`` says why."""

    time_s: float
    kind: str
    cause: str


class BoardStateMachine:
    """The valve board's firmware logic, free of I/O and clocks (``now`` is passed in, seconds).

    Args:
        channels: number of DAC channels.
        max_pressure_bar: the board's own limit; higher set-points are clamped to it.
        full_scale_bar: pressure at DAC full scale (the valve's 10 V range).
        dac_bits: DAC resolution; set-points are rounded to ``full_scale_bar / (2**bits - 1)``.
        watchdog_ms: vent everything when no valid frame arrived for this long.
        firmware: name/version reported by VER (no spaces).
    """

    def __init__(self, channels: int = 7, max_pressure_bar: float = 2.5, *, full_scale_bar: float = 6.0,
                 dac_bits: int = 12, watchdog_ms: float = 250.0, firmware: str = "softarm-emu/0.1.0") -> None:
        if not (isinstance(channels, int) and 1 <= channels <= 16):
            raise ValueError(f"channels: expected 1..16, got {channels!r}")
        if not (0 < max_pressure_bar <= full_scale_bar and math.isfinite(full_scale_bar)):
            raise ValueError(f"max_pressure_bar: expected 0 < {max_pressure_bar!r} <= full_scale_bar "
                             f"({full_scale_bar!r})")
        if not (isinstance(dac_bits, int) and 8 <= dac_bits <= 16):
            raise ValueError(f"dac_bits: expected 8..16, got {dac_bits!r}")
        if not watchdog_ms > 0:
            raise ValueError(f"watchdog_ms: expected a positive duration, got {watchdog_ms!r}")
        self.lsb_mbar = full_scale_bar * 1000.0 / (2**dac_bits - 1)
        self.max_mbar = math.floor(max_pressure_bar * 1000.0)
        self._max_code = min(2**dac_bits - 1, math.floor(self.max_mbar / self.lsb_mbar))
        self._watchdog_s = watchdog_ms / 1000.0
        self._firmware = firmware
        self._codes = [0] * channels
        self._deadline: float | None = None
        self.estop = False
        self._watchdog_unreported = False
        self.events: list[BoardEvent] = []
        self.frames_received = 0
        self.commands: collections.Counter[str] = collections.Counter()  # intact frames received, by verb
        self.recent_commands: collections.deque[str] = collections.deque(maxlen=256)  # their verbs, in order
        self.executed: collections.Counter[str] = collections.Counter()  # commands carried out (re-sends not)
        self.resends = 0  # intact frames identical to the one before: answered again, not carried out
        self.naks_sent = 0
        self.unreadable_frames = 0  # lines answered with a "?" NAK (reported in the status, stops at MAX_COUNT)
        self.watchdog_trips = 0
        self.peak_mbar = 0.0  # the highest set-point any channel was ever driven to
        self._last_frame: Frame | None = None  # the last intact numbered frame, and the reply it got
        self._last_reply = b""
        self._wdt_in_last_reply = False  # that reply reported a watchdog vent
        self._handlers = {"VER": self._on_ver, "STAT": self._on_stat, "HB": self._on_stat, "SET": self._on_set,
                          "VENT": self._on_vent, "ESTOP": self._on_estop, "CLR": self._on_clr}

    @property
    def channels(self) -> int:
        return len(self._codes)

    @property
    def setpoints_mbar(self) -> np.ndarray:
        """Applied set-points (after clamping and DAC rounding), millibar, one per channel."""
        return np.array(self._codes, dtype=float) * self.lsb_mbar

    def version(self) -> BoardVersion:
        return BoardVersion(PROTOCOL_VERSION, self._firmware, self.channels, self.max_mbar,
                            round(self.lsb_mbar * 1000.0), round(self._watchdog_s * 1000.0))

    def status(self) -> BoardStatus:
        return BoardStatus(self.estop, self._watchdog_unreported,
                           tuple(round(c * self.lsb_mbar) for c in self._codes), self.unreadable_frames)

    # --- inputs ---------------------------------------------------------------------------

    def receive(self, line: bytes, now: float) -> bytes:
        """Handle one received line and return the reply frame (never raises on bad input).

        An intact frame identical to the previous intact one (same seq, verb and arguments) is the
        host re-sending a command whose reply it missed: it is not carried out a second time, so a
        retry never stacks a command on the board, and it is answered again: with the same NAK or
        version, or with the status as it is now (a vent by the watchdog or the button since the
        first answer shows at once; a ``wdt=1`` the first answer carried is carried again, since
        that answer may be the one the host missed).
        """
        if line == LineSplitter.OVERFLOW:
            return self._unreadable("FRAME")
        try:
            frame = decode(line)
        except ProtocolError as e:
            return self._unreadable(e.reason)
        if frame.seq is None:
            return self._unreadable("FRAME")
        self.frames_received += 1
        self.commands[frame.verb] += 1
        self.recent_commands.append(frame.verb)
        self._deadline = now + self._watchdog_s  # any intact frame feeds the watchdog, a re-send too
        if frame == self._last_frame:
            self.resends += 1
            if frame.verb == "VER" or decode(self._last_reply).verb == NAK:
                return self._last_reply
            return self._ack_status(frame.seq, resend=True)
        self._wdt_in_last_reply = False
        reply = self._carry_out(frame, now)
        self._last_frame, self._last_reply = frame, reply
        return reply

    def _carry_out(self, frame: Frame, now: float) -> bytes:
        handler = self._handlers.get(frame.verb)
        if handler is None:
            return self._nak(frame.seq, "VERB")
        if frame.verb != "SET" and frame.args:
            return self._nak(frame.seq, "ARGS")
        self.executed[frame.verb] += 1
        return handler(frame.seq, frame.args, now)

    def tick(self, now: float) -> None:
        """Run the watchdog: vent once the last valid frame is older than ``watchdog_ms``."""
        if self._deadline is not None and now > self._deadline:
            self._deadline = None
            if any(self._codes):
                self._vent(now, "watchdog")
                self._watchdog_unreported = True
                self.watchdog_trips += 1

    def press_estop(self, now: float, cause: str = "button") -> None:
        """Latch the e-stop (the physical button): vent and refuse SET until CLR."""
        self.estop = True
        self.events.append(BoardEvent(now, "estop", cause))
        self._vent(now, "estop")

    # --- command handlers -----------------------------------------------------------------

    def _on_ver(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        return encode(seq, ACK, *self.version().fields())

    def _on_stat(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        return self._ack_status(seq)

    def _on_set(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        if len(args) != self.channels or not all(a.isdigit() and len(a) <= 5 and int(a) <= 65535 for a in args):
            return self._nak(seq, "ARGS")
        if self.estop:
            return self._nak(seq, "ESTOP")
        self._codes = [min(round(int(a) / self.lsb_mbar), self._max_code) for a in args]
        self.peak_mbar = max(self.peak_mbar, max(self._codes) * self.lsb_mbar)
        return self._ack_status(seq)

    def _on_vent(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        self._vent(now, "VENT command")
        return self._ack_status(seq)

    def _on_estop(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        self.press_estop(now, "ESTOP command")
        return self._ack_status(seq)

    def _on_clr(self, seq: int, args: tuple[str, ...], now: float) -> bytes:
        if self.estop:
            self.estop = False
            self.events.append(BoardEvent(now, "clear", "CLR command"))
        return self._ack_status(seq)

    # --- helpers --------------------------------------------------------------------------

    def _vent(self, now: float, cause: str) -> None:
        self._codes = [0] * self.channels
        self.events.append(BoardEvent(now, "vent", cause))

    def _ack_status(self, seq: int, resend: bool = False) -> bytes:
        wdt = self._watchdog_unreported or (resend and self._wdt_in_last_reply)
        reply = encode(seq, ACK, *dataclasses.replace(self.status(), watchdog_tripped=wdt).fields())
        self._watchdog_unreported = False  # reported once: in this reply (and the answers to its re-sends)
        self._wdt_in_last_reply = wdt
        return reply

    def _nak(self, seq: int | None, reason: str) -> bytes:
        self.naks_sent += 1
        return encode(seq, NAK, reason)

    def _unreadable(self, reason: str) -> bytes:
        self.unreadable_frames = min(self.unreadable_frames + 1, MAX_COUNT)
        return self._nak(None, reason)


class BoardEmulator:
    """``BoardStateMachine`` served on a pseudo-terminal by a background thread.

    Args: as ``BoardStateMachine``; ``reply_delay_s`` adds a fixed latency to every reply: each
    reply leaves that long after its command arrived, while the board keeps reading (the latency
    of a USB-serial bridge or of a busy firmware loop, not a board that takes that long per command).

    Example:
        >>> board = BoardEmulator(channels=7, max_pressure_bar=2.5)
        >>> port = board.start_pty()        # e.g. "/dev/pts/3"; open it with SerialValveBank
        >>> board.setpoints_bar             # what the valves are driven to
        >>> board.stop()
    """

    def __init__(self, channels: int = 7, max_pressure_bar: float = 2.5, *, full_scale_bar: float = 6.0,
                 dac_bits: int = 12, watchdog_ms: float = 250.0, firmware: str = "softarm-emu/0.1.0",
                 reply_delay_s: float = 0.0) -> None:
        self._board = BoardStateMachine(channels, max_pressure_bar, full_scale_bar=full_scale_bar,
                                        dac_bits=dac_bits, watchdog_ms=watchdog_ms, firmware=firmware)
        self._reply_delay_s = float(reply_delay_s)
        self._lock = threading.Lock()  # the serving thread and the accessors share the board
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fds: tuple[int, int] | None = None
        self._link_up = True
        self._rewrite: Callable[[Frame, Frame], Frame] | None = None
        self._to_board: Callable[[bytes], bytes] | None = None
        self._to_host: Callable[[bytes], bytes] | None = None
        self.port: str | None = None

    # --- life cycle -----------------------------------------------------------------------

    def start_pty(self) -> str:
        """Open a pty pair, start serving, and return the path a host opens (the slave)."""
        if self._thread is not None:
            raise RuntimeError("BoardEmulator: already started")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: bytes pass unchanged both ways
        os.set_blocking(master, False)  # a host that stops reading must not block the board
        self._fds = (master, slave)  # keeping the slave open keeps the pty alive between hosts
        self.port = os.ttyname(slave)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="board-emulator", daemon=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        """Stop serving and close the pty; harmless when not started."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None

    def __enter__(self) -> BoardEmulator:
        if self._thread is None:
            self.start_pty()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- what a test or a person observes -------------------------------------------------

    @property
    def setpoints_bar(self) -> np.ndarray:
        """Applied set-points, bar, one per board channel."""
        with self._lock:
            return self._board.setpoints_mbar / 1000.0

    @property
    def lsb_bar(self) -> float:
        """One DAC step, bar."""
        return self._board.lsb_mbar / 1000.0

    @property
    def estop(self) -> bool:
        with self._lock:
            return self._board.estop

    @property
    def events(self) -> list[BoardEvent]:
        with self._lock:
            return list(self._board.events)

    @property
    def frames_received(self) -> int:
        with self._lock:
            return self._board.frames_received

    @property
    def commands(self) -> dict[str, int]:
        """Intact frames received so far, by verb."""
        with self._lock:
            return dict(self._board.commands)

    @property
    def recent_commands(self) -> list[str]:
        """Verbs of the last 256 intact frames received, oldest first (the last one is ``[-1]``)."""
        with self._lock:
            return list(self._board.recent_commands)

    @property
    def executed(self) -> dict[str, int]:
        """Commands carried out so far, by verb (a re-sent frame the board recognised is not counted again)."""
        with self._lock:
            return dict(self._board.executed)

    @property
    def resends(self) -> int:
        """Re-sent frames answered without carrying the command out again."""
        with self._lock:
            return self._board.resends

    @property
    def naks_sent(self) -> int:
        with self._lock:
            return self._board.naks_sent

    @property
    def unreadable_frames(self) -> int:
        """Lines the board could not read (answered with a "?" NAK); the count its status reports."""
        with self._lock:
            return self._board.unreadable_frames

    @property
    def peak_setpoint_bar(self) -> float:
        """The highest set-point any channel was driven to since the board started, bar."""
        with self._lock:
            return self._board.peak_mbar / 1000.0

    @property
    def watchdog_trips(self) -> int:
        with self._lock:
            return self._board.watchdog_trips

    # --- what a test or a person does to the board ----------------------------------------

    def press_estop(self) -> None:
        """Press the e-stop button: vent and latch until the host sends CLR."""
        with self._lock:
            self._board.press_estop(time.monotonic())

    def cut_link(self) -> None:
        """Simulate an unplugged cable: ignore every byte and answer nothing (the watchdog still runs)."""
        self._link_up = False

    def restore_link(self) -> None:
        self._link_up = True

    def rewrite_replies(self, rewrite: Callable[[Frame, Frame], Frame] | None) -> None:
        """Simulate a faulty firmware: send ``rewrite(command, reply)`` instead of each reply.

        ``command`` is the frame the board received (a garbage line arrives as ``Frame(None,
        "GARBAGE")``), ``reply`` the correct answer, already applied to the board's state. The
        rewritten frame is encoded with a valid checksum, so the host reads a well-framed reply
        with the wrong content. ``None`` restores correct replies.
        """
        self._rewrite = rewrite

    def distort(self, to_board: Callable[[bytes], bytes] | None = None,
                to_host: Callable[[bytes], bytes] | None = None) -> None:
        """Simulate a noisy cable: pass the bytes of each direction through a function.

        ``to_board`` gets every chunk the board reads (any size, frames may be cut anywhere);
        ``to_host`` gets each reply frame before it is written, so noise it adds in front lands
        between two frames. ``None`` (the default for both) restores a clean line.
        """
        self._to_board, self._to_host = to_board, to_host

    # --- serving --------------------------------------------------------------------------

    def _serve(self) -> None:
        master = self._fds[0]
        splitter = LineSplitter()
        outbox: collections.deque[tuple[float, bytes]] = collections.deque()  # (when to send, reply), in order
        while not self._stop.is_set():
            wait_s = 0.002 if not outbox else min(0.002, max(0.0, outbox[0][0] - time.monotonic()))
            readable, _, _ = select.select([master], [], [], wait_s)
            if readable:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, OSError):
                    data = b""
                if not self._link_up:
                    data = b""
                to_board = self._to_board
                if to_board is not None and data:
                    data = to_board(data)
                for line in splitter.feed(data):
                    outbox.append((time.monotonic() + self._reply_delay_s, self._answer(line)))
            while outbox and outbox[0][0] <= time.monotonic():
                reply = outbox.popleft()[1]
                to_host = self._to_host
                if to_host is not None:
                    reply = to_host(reply)
                if self._link_up:
                    with contextlib.suppress(OSError):  # nobody reading: a UART would drop the bytes too
                        os.write(master, reply)
            with self._lock:
                self._board.tick(time.monotonic())

    def _answer(self, line: bytes) -> bytes:
        with self._lock:
            reply = self._board.receive(line, time.monotonic())
        rewrite = self._rewrite
        if rewrite is not None:
            try:
                command = decode(line)
            except ProtocolError:
                command = Frame(None, "GARBAGE")
            answer = rewrite(command, decode(reply))
            reply = encode(answer.seq, answer.verb, *answer.args)
        return reply


def main(argv: list[str] | None = None) -> int:
    """Serve an emulated board until Ctrl-C, printing its port and every vent, e-stop and clear."""
    parser = argparse.ArgumentParser(
        prog="python -m hardware.emulator",
        description="Example: python -m hardware.emulator --link /tmp/softarm-valves\n\n"
                    "Emulate the valve-driver board on a pseudo-terminal so the rig backend runs without hardware.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--channels", type=int, default=7)
    parser.add_argument("--max-pressure-bar", type=float, default=2.5)
    parser.add_argument("--link", type=Path, help="also expose the port under this stable path (a symlink)")
    args = parser.parse_args(argv)
    link = args.link
    if link is not None and (link.exists() or not link.parent.is_dir()) and not link.is_symlink():
        # a stale link of an earlier run is replaced; a real file or a missing folder is the user's to fix
        parser.error(f"--link {link}: " + ("a file is there (only an old link would be replaced)" if link.exists()
                                          else f"the folder {link.parent} does not exist"))
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # clean up the link on `kill` as on Ctrl-C
    try:
        board = BoardEmulator(channels=args.channels, max_pressure_bar=args.max_pressure_bar)
    except ValueError as e:  # the board's own checks: channels 1..16, 0 < limit <= full scale
        key, _, rest = str(e).partition(":")
        parser.error(f"--{key.replace('_', '-')}:{rest}")
    port = board.start_pty()
    if link is not None:
        try:
            if link.is_symlink():
                link.unlink()
            link.symlink_to(port)
        except OSError as e:
            board.stop()
            parser.error(f"--link {link}: {e.strerror or e}")
    print(f"emulated valve board on {link or port} ({args.channels} channels, limit {args.max_pressure_bar} bar)"
          f"{f' -> {port}' if link else ''}; Ctrl-C to stop", flush=True)
    seen = 0
    try:
        while True:
            time.sleep(0.2)
            events = board.events
            for event in events[seen:]:
                print(f"{event.time_s:12.3f}  {event.kind:5s}  {event.cause}", flush=True)
            seen = len(events)
    except KeyboardInterrupt:
        pass
    finally:
        board.stop()
        if link is not None and link.is_symlink():
            link.unlink()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
