"""Valve-link speed: command round trip and set-point update rate, over a pty against the emulated board.

    python benchmarks/valves.py [--commands 2000] [--seconds 3]

Targets (issue 4): median round trip under 5 ms, at least 100 set-point updates per second.
A pty moves bytes at memory speed; the wire time a real UART adds is printed beside the
figures, since at 115200 baud it alone exceeds the target (use USB CDC or a faster rate).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hardware.emulator import BoardEmulator
from hardware.protocol import BoardStatus, encode
from hardware.valves import SerialValveBank

CHANNELS = ("s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b", "s3")
MEDIAN_TARGET_MS = 5.0
RATE_TARGET_HZ = 100.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--commands", type=int, default=2000, help="SET and STAT round trips to time")
    parser.add_argument("--seconds", type=float, default=3.0, help="duration of the update-rate run")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)

    with BoardEmulator(channels=len(CHANNELS), max_pressure_bar=2.5) as board, \
            SerialValveBank(board.port, CHANNELS, max_pressure_bar=2.5) as bank:
        set_ms, stat_ms = [], []
        for _ in range(args.commands):
            pressures = rng.uniform(0.0, 2.5, len(CHANNELS))
            started = time.perf_counter()
            bank.set_pressures(pressures)
            set_ms.append((time.perf_counter() - started) * 1000.0)
            started = time.perf_counter()
            bank.status()
            stat_ms.append((time.perf_counter() - started) * 1000.0)

        updates, started = 0, time.perf_counter()
        while time.perf_counter() - started < args.seconds:
            bank.set_pressures(np.full(len(CHANNELS), 2.5 * (updates % 51) / 50))  # the paper's 0.05 bar ramp
            updates += 1
        rate_hz = updates / (time.perf_counter() - started)
        trips = board.watchdog_trips

    print(f"valve link over a pty, emulated board, {args.commands} round trips each")
    for name, samples in (("SET + ACK", set_ms), ("STAT + ACK", stat_ms)):
        median, p95, worst = np.percentile(samples, [50, 95, 100])
        print(f"  {name:10s} round trip: median {median:.3f} ms, p95 {p95:.3f} ms, max {worst:.3f} ms")
    print(f"  set-point updates: {rate_hz:.0f} per second over {args.seconds:g} s (watchdog trips: {trips})")
    median = float(np.median(set_ms))
    verdict = "met" if median < MEDIAN_TARGET_MS and rate_hz >= RATE_TARGET_HZ else "MISSED"
    print(f"  targets (median < {MEDIAN_TARGET_MS:g} ms, >= {RATE_TARGET_HZ:g} updates/s): {verdict}")

    set_bytes = len(encode(65535, "SET", *[2500] * len(CHANNELS)))
    ack_bytes = len(encode(65535, "ACK", *BoardStatus(False, False, (2500,) * len(CHANNELS)).fields()))
    print(f"  wire time a UART adds per SET round trip ({set_bytes} + {ack_bytes} bytes, 10 bits each):")
    for baud in (115200, 460800, 921600):
        print(f"    {baud:7d} baud: {(set_bytes + ack_bytes) * 10 / baud * 1000:.2f} ms")
    return 0 if verdict == "met" else 1


if __name__ == "__main__":
    raise SystemExit(main())
