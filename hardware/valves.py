"""Proportional valves behind a valve-driver board on a serial link (protocol: ``hardware/PROTOCOL.md``).

Safety lives on both ends. Here: set-points are validated by ``ValveBank`` before they are
encoded (and capped again at the millibar step), heartbeats keep the board's watchdog fed,
every reply's status is checked, and the valves are vented on ``close()``, on an exception in
the caller's ``with`` block, on SIGINT/SIGTERM and at interpreter exit. A link that stops
answering, a watchdog vent, a latched e-stop or a reply the host cannot read is never silent:
the heartbeat records it, and ``check()`` or the next call raises it.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import logging
import os
import signal
import threading
import time
import weakref
from collections.abc import Mapping, Sequence

import numpy as np
import serial

try:  # pyserial's POSIX port raises termios.error (not an OSError) when the other end of a pty is gone
    import termios

    _PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, termios.error)
except ImportError:  # Windows
    _PORT_ERRORS = (serial.SerialException, OSError)

from hardware.errors import (
    BoardReplyError,
    DeviceError,
    EStopError,
    LinkLostError,
    NotConnectedError,
    VentedBySignalError,
    WrongTypeError,
)
from hardware.interfaces import DEFAULT_CLAMP_TOLERANCE, ValveBank, check_integer, check_number
from hardware.protocol import (
    ACK,
    DEFAULT_BAUD,
    MAX_MBAR,
    NAK,
    PROTOCOL_VERSION,
    SEQ_MODULO,
    BoardStatus,
    BoardVersion,
    Frame,
    LineSplitter,
    ProtocolError,
    bar_to_mbar,
    decode,
    encode,
)

_log = logging.getLogger(__name__)

# Bounds of the constructor's arguments: wide, but finite, so a slip is an error naming the argument.
MIN_BAUD, MAX_BAUD = 300, 20_000_000
MAX_WAIT_S = 10.0  # reply_timeout_s and heartbeat_s
MAX_RETRIES = 10
MAX_BOARD_CHANNEL = 255


class SerialValveBank(ValveBank):
    """A ``ValveBank`` driving the valve-driver board over any pyserial port or URL.

    Args:
        port: a device (``/dev/ttyACM0``, ``/dev/serial/by-id/...``, a pty) or a pyserial URL
            (``socket://host:port``, ``loop://``).
        channels: valve names in command order, each on the board channel of its position; or a
            mapping name -> board channel index (0-based, the position in the SET frame).
            Board channels without a name are held at 0 bar.
        max_pressure_bar: host-side limit, (0, 65.535] bar; must not exceed the board's own limit.
        baud: serial rate, 300 .. 20000000 (ignored by URLs without one).
        clamp: clamp set-points slightly out of range (within ``clamp_tolerance``) to [0, max] with a
            warning instead of raising.
        clamp_tolerance: how far out of range ``clamp`` reaches, a fraction of max_pressure_bar in [0, 0.5].
        reply_timeout_s: how long each attempt waits for the reply, (0, 10] s.
        retries: re-sends of the same frame after a timeout, 0 .. 10.
        heartbeat_s: longest silence on the link, (0, 10] s; must stay under half the board's watchdog.

    Raises:
        WrongTypeError (a ``TypeError`` and a ``ValueError``): an argument of the wrong type
            (``max_pressure_bar=True``, ``retries=2.0``, a string as the channel list).
        ValueError: bad channel names or board channels, or a number outside its range (NaN and
            infinity included); the message names the argument and the allowed range.
    """

    def __init__(self, port: str, channels: Sequence[str] | Mapping[str, int], max_pressure_bar: float, *,
                 baud: int = DEFAULT_BAUD, clamp: bool = False, clamp_tolerance: float = DEFAULT_CLAMP_TOLERANCE,
                 reply_timeout_s: float = 0.05, retries: int = 2, heartbeat_s: float = 0.08) -> None:
        if not isinstance(port, str | os.PathLike):
            raise WrongTypeError(f"port: expected a serial device path or a pyserial URL, got {port!r}")
        if not str(port).strip():
            raise ValueError("port: expected a serial device path or a pyserial URL, got an empty string")
        if isinstance(channels, str | bytes) or not isinstance(channels, Sequence | Mapping):
            raise WrongTypeError(f"channels: expected a list of valve names or a mapping name -> board channel, "
                                 f"got {channels!r}")
        names = list(channels)
        check_number("max_pressure_bar", max_pressure_bar, 0.0, MAX_MBAR / 1000.0, "bar", low_open=True)
        super().__init__(names, max_pressure_bar, clamp, clamp_tolerance)
        board = [channels[n] for n in names] if isinstance(channels, Mapping) else list(range(len(names)))
        for name, index in zip(names, board, strict=True):
            if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index <= MAX_BOARD_CHANNEL:
                raise ValueError(f"channel {name}: board channel must be a non-negative integer "
                                 f"(0 .. {MAX_BOARD_CHANNEL}), got {index!r}")
        if len(set(board)) != len(board):
            raise ValueError(f"channels: two names share a board channel in {dict(zip(names, board, strict=True))}")
        self._port = str(port)
        self._baud = check_integer("baud", baud, MIN_BAUD, MAX_BAUD)
        self._board_channels = tuple(board)
        self._reply_timeout_s = check_number("reply_timeout_s", reply_timeout_s, 0.0, MAX_WAIT_S, "s", low_open=True)
        self._retries = check_integer("retries", retries, 0, MAX_RETRIES)
        self._heartbeat_s = check_number("heartbeat_s", heartbeat_s, 0.0, MAX_WAIT_S, "s", low_open=True)
        self._serial: serial.SerialBase | None = None
        self._lock = threading.Lock()  # one exchange at a time: caller, heartbeat, signal handler
        self._lock_owner: int | None = None
        self._seq = 0
        self._splitter = LineSplitter()
        self._lines: collections.deque[bytes] = collections.deque()
        self._unreadable_replies = 0
        self._version: BoardVersion | None = None
        self._status: BoardStatus | None = None
        self._link_dead = False
        self._vented_by_signal = False  # set by the signal handler's vent; refuses SET until reconnect
        self._fault: DeviceError | None = None  # why set-points are refused until reconnect / clear_estop
        self._fault_reported = True
        self._last_tx = 0.0
        self._heartbeat_stop = threading.Event()
        self._heartbeat: threading.Thread | None = None

    def __repr__(self) -> str:
        return f"SerialValveBank({self._port!r}, channels={list(self.channels)})"

    # --- ValveBank ------------------------------------------------------------------------

    @property
    def is_connected(self) -> bool:
        return self._serial is not None

    def connect(self) -> None:
        """Open the port, check the board's version and limits, vent, and start heartbeats.

        Raises:
            DeviceError: already connected, the port cannot be opened, or the board's protocol,
                channel count or limit does not fit this bank.
            LinkLostError (a ``ConnectionError``): the board did not answer.
        """
        if self.is_connected:
            raise DeviceError(f"{self!r}: connect() while already connected")
        try:
            self._serial = serial.serial_for_url(self._port, baudrate=self._baud, timeout=self._reply_timeout_s,
                                                 write_timeout=0.5)
        except (serial.SerialException, ValueError, OSError) as e:
            raise DeviceError(f"could not open valve port {self._port!r}: {e}; check [rig.valves] port "
                              "(a device such as /dev/ttyACM0 or a pyserial URL) and that no other program "
                              "holds it") from e
        self._link_dead, self._fault, self._fault_reported = False, None, True
        self._vented_by_signal = False
        self._splitter, self._lines = LineSplitter(), collections.deque()
        self._unreadable_replies = 0
        try:
            self._serial.reset_input_buffer()
            self._version = None
            self._version = self._check_version(self._exchange("VER")[1])
            self._exchange("VENT", connecting=True)
            self._setpoints_bar = np.zeros(len(self.channels))  # the board starts vented, whatever was set before
        except BaseException as e:
            with contextlib.suppress(*_PORT_ERRORS):
                self._serial.close()
            self._serial = None
            if isinstance(e, _PORT_ERRORS) and not isinstance(e, DeviceError):  # LinkLostError is an OSError too
                raise DeviceError(f"valve port {self._port!r} failed while connecting ({_describe(e)}); check the "
                                  "cable and that the board is powered") from e
            raise
        self._heartbeat_stop.clear()
        self._heartbeat = threading.Thread(target=self._keep_alive, name=f"valves-heartbeat {self._port}",
                                           daemon=True)
        self._heartbeat.start()
        _EMERGENCY_VENT.add(self)

    def _apply(self, setpoints_bar: np.ndarray) -> None:
        sent = [0] * self._version.channels
        for board_channel, bar in zip(self._board_channels, setpoints_bar, strict=True):
            sent[board_channel] = bar_to_mbar(float(bar), self.max_pressure_bar)  # the last check before the wire
        _, status = self._exchange("SET", *sent, refuse_if_faulted=True)
        tolerance_mbar = self._version.lsb_umbar / 2000.0 + 1.0
        for name, board_channel in zip(self.channels, self._board_channels, strict=True):
            applied = status.setpoints_mbar[board_channel]
            if abs(applied - sent[board_channel]) > tolerance_mbar:
                self.vent()
                raise DeviceError(f"channel {name} (board channel {board_channel}): the board applied {applied} "
                                  f"mbar instead of {sent[board_channel]} mbar; valves vented")

    def _vent(self) -> None:
        if self._link_dead:
            self._blind_vent()
        else:
            self._exchange("VENT")
        if self._fault is not None and not self._fault_reported:
            self._fault_reported = True
            raise type(self._fault)(str(self._fault)) from self._fault

    def _disconnect(self) -> None:
        _EMERGENCY_VENT.discard(self)
        self._heartbeat_stop.set()
        if self._heartbeat is not None and self._heartbeat is not threading.current_thread():
            self._heartbeat.join(timeout=2.0)
        self._heartbeat = None
        ser, self._serial = self._serial, None
        if ser is not None:
            with contextlib.suppress(*_PORT_ERRORS):  # a port whose other end is gone: released all the same
                ser.close()

    def check(self) -> None:
        """Raise the fault recorded since connect, if any (see ``ValveBank.check``).

        The heartbeat thread records what it meets between commands: the board stopped answering
        (``LinkLostError``), its watchdog vented the valves (``LinkLostError``), its e-stop is
        latched (``EStopError``), or it answered with fields the host cannot read
        (``BoardReplyError``). The fault stays until ``connect()`` again (or ``clear_estop()`` for
        an e-stop), so every call raises it; a closed or never connected bank has nothing to report.
        """
        if self.is_connected:
            self._raise_fault()

    @property
    def fault(self) -> DeviceError | None:
        """The fault ``check()`` would raise, without raising it (None while all is well or disconnected)."""
        return self._fault if self.is_connected else None

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.close()
        except DeviceError as close_error:
            if exc is None:
                raise
            # Keep the caller's exception in front; the close failure rides along as a note.
            _log.error("%r: %s", self, close_error)
            exc.add_note(f"while venting {self!r}: {close_error}")

    # --- board queries --------------------------------------------------------------------

    @property
    def port(self) -> str:
        return self._port

    @property
    def baud(self) -> int:
        return self._baud

    @property
    def board_channels(self) -> dict[str, int]:
        """Board channel index of each valve name."""
        return dict(zip(self.channels, self._board_channels, strict=True))

    @property
    def version(self) -> BoardVersion:
        """The board's answer to VER at connect. Raises ``NotConnectedError`` before."""
        if self._version is None or not self.is_connected:
            raise NotConnectedError(f"{self!r}: version before connect()")
        return self._version

    @property
    def unreadable_replies(self) -> int:
        """Lines from the board this host could not read since ``connect()`` (noise on the way back).

        The other direction is counted by the board: ``status().unreadable_frames``.
        """
        return self._unreadable_replies

    def status(self) -> BoardStatus:
        """Ask the board for its e-stop state, watchdog flag, applied set-points and count of
        unreadable frames (sets nothing)."""
        if not self.is_connected:
            raise NotConnectedError(f"{self!r}: status() before connect()")
        if self._link_dead:
            self._raise_fault()
        return self._exchange("STAT")[1]

    def clear_estop(self) -> None:
        """Clear a latched e-stop (after the button was released); set-points restart from 0 bar.

        Raises:
            EStopError: the board still reports the e-stop (the button is held).
        """
        if not self.is_connected:
            raise NotConnectedError(f"{self!r}: clear_estop() before connect()")
        _, status = self._exchange("CLR", connecting=True)
        if status.estop:
            raise EStopError(f"{self!r}: the board still reports its e-stop; release it and try again")
        if isinstance(self._fault, EStopError):
            self._fault, self._fault_reported = None, True
        self._setpoints_bar = np.zeros(len(self.channels))

    # --- the link -------------------------------------------------------------------------

    def _exchange(self, verb: str, *args: object, connecting: bool = False,
                  refuse_if_faulted: bool = False) -> tuple[Frame, BoardStatus | BoardVersion]:
        with self._lock:
            self._lock_owner = threading.get_ident()
            try:
                if self._is_closing and verb != "VENT":
                    # Checked under the wire lock: close() marks the bank closing before its VENT
                    # takes this lock, so nothing (a SET, a heartbeat, a query) follows the VENT.
                    raise NotConnectedError(f"{self!r}: {verb} refused: the bank is closing")
                if self._vented_by_signal and verb == "SET":
                    raise VentedBySignalError(f"{self!r}: SET refused: a signal vented the valves; close() and "
                                              "connect() again to continue")
                if refuse_if_faulted:  # checked under the lock: the heartbeat may have just recorded one
                    self._raise_fault()
                return self._exchange_locked(verb, args, connecting)
            finally:
                self._lock_owner = None

    def _exchange_locked(self, verb: str, args: tuple, connecting: bool) -> tuple[Frame, BoardStatus | BoardVersion]:
        """Send one command and return its ACK with the parsed payload (VER: the version, else
        the status).

        Stale input is dropped first. Only a reply carrying this command's ``seq`` answers it; after
        each ``reply_timeout_s`` without one the identical frame is sent again (``retries`` times),
        and a reply to any of the attempts counts: a board that answers late is heard instead of
        being sent more, and the board carries a re-sent frame out only once (``hardware/PROTOCOL.md``).

        Raises:
            LinkLostError: no answer after every attempt, or the port failed; also a watchdog vent.
            EStopError: the e-stop is latched.
            BoardReplyError: an ACK whose fields cannot be read (recorded, valves vented).
            DeviceError: the board refused the command.
        """
        ser = self._serial
        if ser is None:
            raise NotConnectedError(f"{self!r}: {verb} before connect()")
        seq = self._next_seq()
        frame = encode(seq, verb, *args)
        attempts = 1 + self._retries
        reply = None
        try:
            self._drop_stale_input(ser)
            for _ in range(attempts):
                ser.write(frame)
                self._last_tx = time.monotonic()
                reply = self._await_reply(ser, seq)
                if reply is not None:
                    break
        except _PORT_ERRORS as e:
            raise self._lose_link(f"{self._port}: serial I/O failed during {verb} ({_describe(e)}): the valve "
                                  "board's link is lost; the board's watchdog vents its valves when it hears "
                                  "nothing") from e
        if reply is None:
            hint = (f"check that the board is powered and flashed, the cable, the baud rate ({self._baud}) and "
                    "that no other program holds the port")
            raise self._lose_link(f"the valve board on {self._port} did not answer {verb} ({attempts} attempts, "
                                  f"{self._reply_timeout_s * 1000:.0f} ms each): {hint}")
        if reply.verb == NAK:
            reason = reply.args[0] if reply.args else "?"
            if reason == "ESTOP":
                raise self._record(EStopError(f"{self!r}: the board refused {verb}: its e-stop is latched and "
                                              "every valve is vented; release it, then call clear_estop()"))
            raise DeviceError(f"{self!r}: the board refused {verb} ({reason}); protocol mismatch?")
        if verb == "VER":
            return reply, self._parse_version(reply)
        status = self._parse_status(verb, reply)
        self._check_status(status, connecting)
        return reply, status

    def _drop_stale_input(self, ser: serial.SerialBase) -> None:
        """Forget what arrived before this command: late replies, NAKs to line noise, half a line of noise."""
        ser.reset_input_buffer()
        self._splitter = LineSplitter()
        self._lines.clear()

    def _await_reply(self, ser: serial.SerialBase, seq: int) -> Frame | None:
        """The board's ACK or NAK carrying ``seq``, or None after ``reply_timeout_s``.

        Everything else is skipped: lines the checksum rejects (noise from the board's side),
        replies to earlier commands, and NAKs without a sequence number: the board could not read
        *some* line, which may be noise on the cable rather than this command; if it was this
        command, no reply with ``seq`` comes and the caller sends it again.
        """
        deadline = time.monotonic() + self._reply_timeout_s
        while True:
            while self._lines:
                try:
                    reply = decode(self._lines.popleft())
                except ProtocolError:
                    self._unreadable_replies += 1
                    continue
                if reply.seq == seq and reply.verb in (ACK, NAK):
                    return reply
            if time.monotonic() >= deadline:
                return None
            self._lines.extend(self._splitter.feed(ser.read(max(1, ser.in_waiting))))

    def _parse_version(self, reply: Frame) -> BoardVersion:
        try:
            return BoardVersion.parse(reply.args)
        except ProtocolError as e:
            raise self._record(self._bad_reply("VER", reply, str(e))) from e

    def _parse_status(self, verb: str, reply: Frame) -> BoardStatus:
        try:
            status = BoardStatus.parse(reply.args)
        except ProtocolError as e:
            raise self._record(self._bad_reply(verb, reply, str(e))) from e
        if self._version is not None and len(status.setpoints_mbar) != self._version.channels:
            raise self._record(self._bad_reply(verb, reply, f"{len(status.setpoints_mbar)} set-points for "
                                                            f"{self._version.channels} channels"))
        return status

    def _bad_reply(self, verb: str, reply: Frame, problem: str) -> BoardReplyError:
        received = " ".join((reply.verb, *reply.args))
        return BoardReplyError(f"{self!r}: the board answered {verb} with {received!r}, which this host cannot "
                               f"read ({problem}); valves vented; check that its firmware speaks protocol "
                               f"{PROTOCOL_VERSION} (hardware/PROTOCOL.md), then reconnect")

    def _check_status(self, status: BoardStatus, connecting: bool) -> None:
        self._status = status
        if connecting:
            return  # a watchdog vent or e-stop from before this session is not news
        if status.watchdog_tripped:
            raise self._record(LinkLostError(
                f"{self!r}: the board's watchdog vented every valve: it received no frame for "
                f"{self._version.watchdog_ms} ms (the host stalled or the link dropped); reconnect to continue"))
        if status.estop and not isinstance(self._fault, EStopError):
            raise self._record(EStopError(f"{self!r}: the board's e-stop is latched and every valve is vented; "
                                          "release it, then call clear_estop()"))

    def _check_version(self, version: BoardVersion) -> BoardVersion:
        if version.protocol != PROTOCOL_VERSION:
            raise DeviceError(f"valve board on {self._port} speaks protocol {version.protocol}, this host "
                              f"speaks {PROTOCOL_VERSION}; update the firmware or the host")
        if max(self._board_channels) >= version.channels:
            beyond = [f"{name} on {channel}" for name, channel in zip(self.channels, self._board_channels, strict=True)
                      if channel >= version.channels]
            raise DeviceError(f"valve board on {self._port} has {version.channels} channels (0 to "
                              f"{version.channels - 1}); the channel map puts {', '.join(beyond)}")
        if bar_to_mbar(self.max_pressure_bar, self.max_pressure_bar) > version.max_mbar:
            raise DeviceError(f"max_pressure_bar {self.max_pressure_bar} exceeds the limit of the valve board on "
                              f"{self._port} ({version.max_mbar / 1000} bar); lower it in the config")
        if self._heartbeat_s * 2000.0 >= version.watchdog_ms:
            raise DeviceError(f"heartbeat_s {self._heartbeat_s} is too slow for the board's "
                              f"{version.watchdog_ms} ms watchdog; keep it under half of that")
        return version

    def _record(self, fault: DeviceError) -> DeviceError:
        """Remember why set-points are refused, vent at once if the link works, and hand the error back."""
        # Raised in the caller's thread it is reported; raised in the heartbeat thread, the next call reports it.
        # The same fault met again (every heartbeat to a board that keeps answering garbage) is not news.
        if not self._is_standing(fault):
            self._fault, self._fault_reported = fault, threading.current_thread() is not self._heartbeat
        if not self._link_dead and self._serial is not None:
            with contextlib.suppress(Exception):  # best effort: the fault is what gets reported
                self._serial.write(encode(self._next_seq(), "VENT"))
        return fault

    def _is_standing(self, fault: DeviceError) -> bool:
        """``fault`` is the recorded fault, or says the same thing."""
        standing = self._fault
        return standing is fault or (type(standing) is type(fault) and str(standing) == str(fault))

    def _lose_link(self, message: str) -> LinkLostError:
        self._link_dead = True
        self._blind_vent()
        return self._record(LinkLostError(message))

    def _raise_fault(self) -> None:
        if self._fault is not None:
            self._fault_reported = True
            raise type(self._fault)(str(self._fault)) from self._fault

    def _blind_vent(self) -> None:
        """Write a VENT without waiting for the answer (a dead link, or inside a signal handler).

        The leading newline ends any frame this write interrupted, so the board NAKs that
        fragment and still reads the VENT.
        """
        ser = self._serial
        if ser is None:
            return
        try:
            ser.write(b"\n" + encode(self._next_seq(), "VENT"))
            ser.flush()
        except _PORT_ERRORS:
            pass

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) % SEQ_MODULO
        return self._seq

    def _keep_alive(self) -> None:
        """Heartbeat thread: never let the link stay silent longer than ``heartbeat_s``.

        Whatever goes wrong is recorded as the bank's fault (``check()`` and the caller's next
        call raise it); the thread keeps beating so an e-stop can be cleared, and stops only
        when the link is dead or the bank closes.
        """
        logged = None
        while not self._heartbeat_stop.wait(max(0.0, self._last_tx + self._heartbeat_s - time.monotonic())):
            if self._link_dead:
                return
            if time.monotonic() - self._last_tx < self._heartbeat_s:
                continue
            try:
                self._exchange("HB")
            except Exception as e:  # a heartbeat thread that died would leave the link silent
                if self._heartbeat_stop.is_set() or self._is_closing:
                    return
                if isinstance(e, DeviceError):
                    fault = e  # recorded already, unless it was a refusal (NAK)
                else:
                    fault = DeviceError(f"{self!r}: the heartbeat failed ({type(e).__name__}: {e}); a VENT was "
                                        "sent if the link still carries it (the board's watchdog vents "
                                        "otherwise); reconnect to continue")
                    fault.__cause__ = e
                if not self._is_standing(fault):
                    with self._lock:  # its VENT must not interleave with a caller's frame on the wire
                        self._record(fault)
                if str(self._fault) != logged:
                    logged = str(self._fault)
                    _log.error("%s", self._fault)
                if self._heartbeat_stop.wait(self._heartbeat_s):  # never spin on a failure before the write
                    return

    def _emergency_vent(self) -> None:
        """Vent from a signal handler or at exit: a full exchange when possible, else a blind write.

        From here on SET is refused (``VentedBySignalError``) until ``connect()``: a set-point
        already past its checks in another thread when the signal landed cannot follow the vent.
        """
        if self._serial is None:
            return
        self._vented_by_signal = True
        if self._lock_owner != threading.get_ident() and self._lock.acquire(timeout=0.3):
            try:
                self._exchange_locked("VENT", (), True)
                return
            except DeviceError:
                pass
            finally:
                self._lock.release()
        self._blind_vent()


def _describe(error: BaseException) -> str:
    """A port error as one phrase: its name and what it says (termios.error carries a bare tuple)."""
    return f"{type(error).__name__}: {error}"


class _EmergencyVent:
    """Vent every connected bank on SIGINT/SIGTERM (then chain to the previous handler) and at exit."""

    _SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self._banks: weakref.WeakSet[SerialValveBank] = weakref.WeakSet()
        self._previous: dict[int, object] = {}
        atexit.register(self._at_exit)

    def add(self, bank: SerialValveBank) -> None:
        self._banks.add(bank)
        if threading.current_thread() is not threading.main_thread():
            return  # Python only lets the main thread install handlers; atexit still covers this bank
        for signum in self._SIGNALS:
            if signal.getsignal(signum) != self._on_signal:
                self._previous[signum] = signal.getsignal(signum)
                signal.signal(signum, self._on_signal)

    def discard(self, bank: SerialValveBank) -> None:
        self._banks.discard(bank)
        if self._banks or threading.current_thread() is not threading.main_thread():
            return
        for signum, previous in list(self._previous.items()):
            if signal.getsignal(signum) == self._on_signal:
                signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
            del self._previous[signum]

    def _on_signal(self, signum: int, frame) -> None:
        for bank in list(self._banks):
            bank._emergency_vent()
        previous = self._previous.get(signum, signal.SIG_DFL)
        if callable(previous):
            previous(signum, frame)
        elif previous != signal.SIG_IGN:  # default action: die of the same signal, as without us
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)

    def _at_exit(self) -> None:
        for bank in list(self._banks):
            try:
                bank.close()
            except DeviceError as e:
                _log.error("venting %r at exit: %s", bank, e)


_EMERGENCY_VENT = _EmergencyVent()
