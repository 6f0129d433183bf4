"""The one capture loop: the schedule's frames, from whichever devices ``make_devices`` opened.

    for capture in captures(devices, schedule, experiment, stop):
        record = process(capture, estimators, calibration)

The clock brings the experiment to each capture time (the twin's physics, or the wall clock with
the pressure thread), the camera grabs, the truth says what it knows (the exact backbone and depth
on the twin, a depth folder or nothing on the rig) and the archive what the run keeps. The loop
never asks which backend it has.

A stop request ends the captures at once, and a capture that a stop request overtook (it began
after the request) is not handed out. A capture whose slot has already passed when the loop gets
to it (the rig fell behind by more than one capture interval) is dropped and counted in
``stats["dropped"]``, so frames stay aligned with the schedule.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

from bench.devices import Devices, Stop
from bench.experiments import Schedule
from bench.process import Capture


def captures(devices: Devices, schedule: Schedule, experiment, stop: Stop,
             stats: dict | None = None) -> Iterator[Capture]:
    """Run the schedule on ``devices`` and yield each capture.

    Args:
        devices: camera, valves, clock, truth and archive.
        schedule: the pressures and the capture times.
        experiment: the ``[experiment]`` section (settle, lead-in, quasi-static).
        stop: the run's stop flag (every set-point goes through it).
        stats: counts ``dropped`` captures (the loop fell behind the schedule).

    Raises:
        DeviceError: a device failed (``SimulationError`` on the twin; a valve fault met by the
            pressure thread, raised when the captures end).
    """
    stats = stats if stats is not None else {}
    stats.setdefault("dropped", 0)
    try:
        yield from _captures(devices, schedule, experiment, stop, stats)
    finally:
        devices.clock.finish()  # stops and joins the pressure thread, on every path, before the devices close
    devices.clock.raise_fault()  # what the pressure thread met; only when the captures ended by themselves


def _captures(devices: Devices, schedule: Schedule, experiment, stop: Stop, stats: dict) -> Iterator[Capture]:
    clock, camera, valves = devices.clock, devices.camera, devices.valves
    if not clock.start(valves, schedule, experiment, stop):
        return
    times = schedule.capture_times_s
    index = 0
    for i, t_capture in enumerate(times):
        if stop or not clock.wait_until(float(t_capture)):
            return
        if clock.behind(float(times[i + 1]) if i + 1 < len(times) else None):
            stats["dropped"] += 1
            continue
        started_at = time.monotonic()
        timings = clock.take_timings_ms()
        start = time.perf_counter()
        frame = camera.grab()
        timings[devices.grab_name] = (time.perf_counter() - start) * 1e3
        t_s = clock.capture_time(float(t_capture))
        observation = devices.truth.observe(frame) if devices.truth is not None else None
        if stop.came_before(started_at):
            return
        if observation is not None:
            timings.update(observation.timings_ms)
        stored = devices.archive.store(frame, observation)
        yield Capture(
            index=index, t_s=t_s, frame=frame,
            commanded_bar={k: round(float(v), 6) for k, v in valves.setpoints_bar.items()},
            chamber_bar=None if observation is None else observation.chamber_bar,
            sim_time_s=None if observation is None else observation.sim_time_s,
            gt_m=None if observation is None else observation.gt_m,
            depth_units=None if observation is None else observation.depth_units,
            depth_unit_m=None if observation is None else observation.depth_unit_m,
            timings_ms=timings, started_at=started_at, stored=stored)
        index += 1
