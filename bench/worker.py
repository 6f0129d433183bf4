"""Estimating beside the capture loop: a worker thread fed through a small bounded queue.

The capture loop (physics, rendering or the camera) and the estimator use different parts of the
machine: MuJoCo, OpenGL, OpenCV and the estimator's compiled stages release the GIL, so while the
estimator works on frame k the loop can already advance the twin and render frame k + 1. The queue
holds at most ``depth`` frames: a slow estimator holds the loop back instead of letting captures pile
up, and a stop leaves at most that many captured frames to finish (they were captured before the
stop, so they are part of the run).

    with FrameWorker(handle) as worker:       # handle(item) runs in the worker, in order
        for item in items:
            worker.put(item)                   # raises what handle raised, if it failed
        worker.finish()                        # every item handled; raises what handle raised
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

_DONE = object()


class FrameWorker:
    """Runs ``handle`` on each item put, in order, in one background thread.

    Args:
        handle: called with each item; an exception stops the worker and is raised by the next
            ``put`` or by ``finish`` (the items after it are not handled).
        depth: items that may wait in the queue.
        name: the thread's name.
    """

    def __init__(self, handle: Callable[[Any], None], depth: int = 2, name: str = "frame-worker") -> None:
        if depth < 1:
            raise ValueError(f"depth: expected at least 1, got {depth}")
        self._handle = handle
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self.error: BaseException | None = None
        self._failed = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()
        self._finished = False

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _DONE:
                return
            if self._failed.is_set():
                continue  # after a failure the rest is dropped, but the queue keeps draining
            try:
                self._handle(item)
            except BaseException as e:  # noqa: BLE001 - handed to the producer
                self.error = e
                self._failed.set()

    def put(self, item: Any) -> None:
        """Queue ``item``, waiting while the queue is full.

        Raises:
            Whatever ``handle`` raised on an earlier item.
        """
        self._raise()
        while True:
            try:
                self._queue.put(item, timeout=0.05)
                return
            except queue.Full:
                self._raise()

    def finish(self) -> None:
        """Wait until every item put is handled; raise what ``handle`` raised, if it failed."""
        self.close()
        self._raise()

    def close(self) -> None:
        """Let the items put be handled (after a failure: dropped) and end the thread; never raises."""
        if self._finished:
            return
        self._finished = True
        self._queue.put(_DONE)
        self._thread.join()

    def _raise(self) -> None:
        if self._failed.is_set() and self.error is not None:
            error, self.error = self.error, None
            raise error

    def __enter__(self) -> FrameWorker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
