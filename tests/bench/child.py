"""A ``softarm`` process to interrupt: start it, wait for a state of its files or devices, send a signal."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from tests.hardware.polling import wait_until

REPO = Path(__file__).resolve().parents[2]


def interrupt_child(argv: list[str], ready: Callable[[], object], signum: int = signal.SIGINT, *,
                    timeout_s: float = 120.0, timing: dict | None = None) -> tuple[int, str, str]:
    """Run ``python *argv`` in the repository, send ``signum`` once ``ready()`` holds, wait for the end.

    Args:
        timing: if given, receives ``after_signal_s``: wall-clock seconds from the signal to the
            child's exit (a liveness figure for generous bounds, not a speed measurement).

    Returns:
        (exit code, stdout, stderr). The test fails, with the child's output, when ``ready`` never
        holds (or the child ends first); the child is killed on every path.
    """
    child = subprocess.Popen([sys.executable, *argv], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        if not wait_until(lambda: ready() or child.poll() is not None, timeout_s=timeout_s, interval_s=0.05) \
                or not ready():
            child.kill()
            stdout, stderr = child.communicate(timeout=30)
            raise AssertionError(f"the child never got ready (exit {child.returncode}):\n{stdout}\n{stderr}")
        child.send_signal(signum)
        sent = time.monotonic()
        stdout, stderr = child.communicate(timeout=60)
        if timing is not None:
            timing["after_signal_s"] = time.monotonic() - sent
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=30)
    return child.returncode, stdout, stderr


def frames_written(folder: Path) -> int:
    """Lines in a run folder's frames.jsonl so far (0 before it exists)."""
    path = folder / "frames.jsonl"
    return len(path.read_bytes().splitlines()) if path.is_file() else 0
