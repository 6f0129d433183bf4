"""Errors raised by devices; each message says what failed and what to check."""


class DeviceError(RuntimeError):
    """A device could not be opened, configured or used."""


class NotConnectedError(DeviceError):
    """A device was used before ``connect()`` or after ``close()``."""


class VentedBySignalError(NotConnectedError):
    """SIGINT/SIGTERM vented the valves: set-points are refused until the bank is closed and
    connected again, so a command racing the signal cannot pressurise them again."""


class LinkLostError(DeviceError, ConnectionError):
    """A device stopped answering; valves have been vented where possible."""


class BoardReplyError(DeviceError):
    """The valve board answered with a well-framed reply whose fields the host cannot read.

    A firmware or protocol mismatch, or a corrupted board: the host stops trusting it, vents
    where possible and refuses set-points until it reconnects.
    """


class EStopError(DeviceError):
    """The valve board's e-stop is latched: every valve is vented and set-points are refused."""


class SimulationError(DeviceError):
    """A simulated device could not go on: the digital twin's physics went unstable (a NaN, a MuJoCo
    warning, a diverging state). A device fault like any other: a run stops cleanly, keeping its frames."""


class EndOfStreamError(DeviceError):
    """A recorded camera source (video file or image folder) has no more frames."""


class WrongTypeError(TypeError, ValueError):
    """A value of the wrong kind: a boolean where a number of bar belongs, a string given as a list of
    pressures, a set whose order is arbitrary.

    A ``TypeError``, and a ``ValueError`` too, so code that reports bad input by catching
    ``ValueError`` (the bench's configuration and command handlers) reports this as well.
    """
