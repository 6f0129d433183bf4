"""Episodes for the engine tests: module-level (workers import them by name), each a pure function of its
spec except for a marker file that makes a first attempt fail."""

import os
from pathlib import Path


def square(spec: dict) -> dict:
    """The spec's number squared, and the process that computed it."""
    return {"value": spec["x"] ** 2, "pid": os.getpid()}


def fails_first_time(spec: dict) -> dict:
    """Raises on the first attempt (it leaves a marker), answers on the second."""
    marker = Path(spec["marker"])
    if not marker.exists():
        marker.write_text("tried")
        raise RuntimeError(f"first attempt of {spec['x']} fails")
    return square(spec)


def always_fails(spec: dict) -> dict:
    if spec.get("fail"):
        raise ValueError(f"episode {spec['x']} is broken")
    return square(spec)


def dies_first_time(spec: dict) -> dict:
    """Kills its worker process on the first attempt (a crash, as a segfault in a renderer would)."""
    marker = Path(spec["marker"])
    if not marker.exists():
        marker.write_text("died")
        os._exit(3)
    return square(spec)
