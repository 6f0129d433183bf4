"""SIGTERM as an exception for the length of a block, so that what the block started is ended with it.

Python's default for SIGTERM ends the process where it stands: worker processes a study started run
on, orphaned, and a report being written stops without a word. Inside ``sigterm_raises()`` SIGTERM
raises ``Terminated`` in the main thread instead, which unwinds like Ctrl-C's KeyboardInterrupt.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


class Terminated(BaseException):
    """SIGTERM arrived (a BaseException, like KeyboardInterrupt: no ``except Exception`` swallows it)."""


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """While the block runs (in the main thread), SIGTERM raises ``Terminated``; the handler before is
    restored after."""
    def stop(signum, frame):
        raise Terminated()

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, stop) if main else None
    try:
        yield
    finally:
        if main:  # a handler installed outside Python reads back as None: the default then
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def stopped_by(stop: BaseException) -> tuple[str, int]:
    """(what stopped it, the shell's exit code) for ``Terminated`` or ``KeyboardInterrupt``."""
    if isinstance(stop, Terminated):
        return "SIGTERM", 128 + signal.SIGTERM
    return "Ctrl-C", 128 + signal.SIGINT
