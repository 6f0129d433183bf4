"""Speed of the digital twin: physics real-time factor and stereo rendering time.

    python benchmarks/twin_speed.py [--frames 20]

Prints the physics real-time factor (simulated seconds per wall-clock second while the arm
moves under a pressure ramp), the median time to render one raw 1280x720 stereo pair (both
eyes, distortion, noise; with and without the left depth map) with its breakdown per stage, and
the time of a camera grab (a pair as a run captures it) in each scene preset of
``models/scene.toml``, the presets interleaved frame by frame, with its ratio to ``clean``.
Targets (issue 3): physics >= 10x real time; a raw stereo pair <= 120 ms on a 2-core machine.
Issue 10: a lab scene renders within 1.5x of the time a stereo pair took when the issue was filed.
The clean scene renders faster now than then, so the ratio to today's clean scene is the stricter
figure; ``--baseline DIR`` also times the issue's own reference, a checkout from before the lab
scenes (``git worktree add DIR f67e884~1``), in child processes that alternate with this
checkout's presets, so both see the same machine load:

    python benchmarks/twin_speed.py --baseline /tmp/before [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np

from twin.params import ArmParams
from twin.physics import ArmSimulation
from twin.render import StereoRenderer
from twin.rig import StereoRig
from twin.twin import DEFAULT_CONFIG, TwinConfig


def physics_rtf(config: TwinConfig, sim_seconds: float = 10.0) -> float:
    """Real-time factor while every channel ramps 0 -> 2.5 bar, in 0.05 s advances."""
    sim = ArmSimulation(ArmParams.load(config.arm), timestep_s=config.timestep_s)
    n = len(sim.channels)
    steps = int(round(sim_seconds / 0.05))
    start = time.perf_counter()
    for k in range(steps):
        pressure = sim.max_pressure_bar * k / steps
        sim.command(np.array([pressure if i % 2 == 0 else 0.3 * pressure for i in range(n)]))
        sim.advance(0.05)
    return sim_seconds / (time.perf_counter() - start)


def render_times(config: TwinConfig, frames: int) -> dict[str, list[float]]:
    """Per-frame wall times (s) of raw stereo pairs of a moving arm, by stage."""
    rig = StereoRig.load(config.camera)
    sim = ArmSimulation(ArmParams.load(config.arm), timestep_s=config.timestep_s)
    shapes = []
    for k in range(frames):
        sim.command(np.full(len(sim.channels), 0.0) + np.eye(len(sim.channels))[k % 3] * 2.0)
        sim.advance(0.2)
        shapes.append(sim.shape(config.backbone_points))
    times: dict[str, list[float]] = {"pair": [], "pair_no_depth": [], "scene": [], "gl_left": [], "gl_right": [],
                                     "post": []}
    with StereoRenderer(rig, seed=config.seed, tube_sides=config.tube_sides) as renderer:
        print(f"canvas per eye {renderer.canvas_size[0]}x{renderer.canvas_size[1]} for "
              f"{rig.image_size[0]}x{rig.image_size[1]} raw images")
        renderer.render(shapes[0])  # warm-up: shader compilation, buffers
        for shape in shapes:
            start = time.perf_counter()
            renderer.render(shape, depth=True)
            times["pair"].append(time.perf_counter() - start)
            for key in ("scene", "gl_left", "gl_right", "post"):
                times[key].append(renderer.timings_s[key])
            start = time.perf_counter()
            renderer.render(shape, depth=False)
            times["pair_no_depth"].append(time.perf_counter() - start)
    return times


def preset_grab_times(config: TwinConfig, frames: int, presets: list[str] | None = None) -> dict[str, list[float]]:
    """Wall times (s) of ``camera.grab()`` per scene preset (default: all; "" = the config's own scene,
    for checkouts that know no presets), the arm moving, presets interleaved."""
    import dataclasses

    from twin import Twin

    if presets is None:
        from twin.scene import preset_names

        presets = ["clean"] + [name for name in preset_names(config.scene_file) if name != "clean"]
    twins = {name: Twin(dataclasses.replace(config, scene_preset=name) if name else config) for name in presets}
    times: dict[str, list[float]] = {name: [] for name in presets}
    try:
        for twin in twins.values():
            twin.valves.set_pressures({"s1_a": 1.2, "s2_a": 1.5, "s3": 1.0})
            twin.advance(1.5)
            twin.camera.grab()  # warm-up: the static scene is rendered once and cached
        for _ in range(frames):
            for name, twin in twins.items():
                twin.advance(0.084)
                start = time.perf_counter()
                twin.camera.grab()
                times[name].append(time.perf_counter() - start)
    finally:
        for twin in twins.values():
            twin.close()
    return times


# Run in a child process: this file's preset_grab_times on the twin of another checkout. The child puts
# that checkout first on its own sys.path on purpose (an editable install's finder outranks
# PYTHONPATH); this script's own process imports the installed packages only.
_CHILD = """
import json, os, sys
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
checkout, here, frames, presets = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4:]
sys.path[:0] = [checkout, here]
import twin
if not twin.__file__.startswith(checkout):
    raise SystemExit(f"twin imported from {twin.__file__}, not from {checkout}")
import twin_speed
from twin.twin import DEFAULT_CONFIG, TwinConfig
print(json.dumps(twin_speed.preset_grab_times(TwinConfig.load(DEFAULT_CONFIG), frames, presets)))
"""


def grab_times_of(checkout: Path, presets: list[str], frames: int) -> dict[str, list[float]]:
    """Camera-grab wall times (s) per preset of the twin in ``checkout``, from a child process."""
    import json
    import subprocess

    done = subprocess.run([sys.executable, "-c", _CHILD, str(checkout), str(Path(__file__).resolve().parent),
                           str(frames), *presets],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"timing the twin in {checkout} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def against_baseline(baseline: Path, config: TwinConfig, frames: int, rounds: int) -> None:
    """Each preset's grab time against the baseline checkout's pair, children alternating."""
    from twin.scene import preset_names

    here = Path(__file__).resolve().parents[1]
    presets = ["clean"] + [name for name in preset_names(config.scene_file) if name != "clean"]
    before: list[float] = []
    now: dict[str, list[float]] = {name: [] for name in presets}
    for _ in range(rounds):
        before += grab_times_of(baseline, [""], frames)[""]
        for name, values in grab_times_of(here, presets, frames).items():
            now[name] += values
    reference = 1000 * statistics.median(before)
    print(f"\ncamera grab against the baseline checkout {baseline} ({rounds} rounds of {frames} frames, "
          f"children alternating): its pair {reference:.1f} ms")
    for name, values in now.items():
        value = 1000 * statistics.median(values)
        verdict = "met" if value <= 1.5 * reference else "NOT met"
        print(f"  {name:<12} {value:7.1f} ms   {value / reference:5.2f} x baseline   target <= 1.5x: {verdict}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="frames to time (median reported)")
    parser.add_argument("--config", default=str(DEFAULT_CONFIG), help="twin.toml")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="a checkout from before the lab scenes, timed beside this one (issue 10's reference)")
    parser.add_argument("--rounds", type=int, default=3, help="alternations with --baseline")
    args = parser.parse_args(argv)
    config = TwinConfig.load(args.config)
    print(f"machine: {os.cpu_count()} CPUs; OpenGL through EGL (PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']})")
    rtf = physics_rtf(config)
    print(f"physics: {rtf:.1f}x real time (timestep {1000 * config.timestep_s:g} ms)   target >= 10x: "
          f"{'met' if rtf >= 10 else 'NOT met'}")
    times = render_times(config, args.frames)
    ms = {key: 1000 * statistics.median(values) for key, values in times.items()}
    print(f"raw stereo pair with left depth: {ms['pair']:.1f} ms median over {args.frames} frames "
          f"(max {1000 * max(times['pair']):.1f} ms)   target <= 120 ms: {'met' if ms['pair'] <= 120 else 'NOT met'}")
    print(f"raw stereo pair without depth:   {ms['pair_no_depth']:.1f} ms")
    print(f"per 1280x720 view (pair without depth / 2): {ms['pair_no_depth'] / 2:.1f} ms")
    print(f"  stages of a pair: scene update {ms['scene']:.1f} ms, OpenGL left (+ depth) {ms['gl_left']:.1f} ms, "
          f"OpenGL right {ms['gl_right']:.1f} ms, distortion + noise + depth {ms['post']:.1f} ms")
    grabs = {name: 1000 * statistics.median(values) for name, values in preset_grab_times(config, args.frames).items()}
    print("\ncamera grab per scene preset (a raw stereo pair as a run captures it; median ms, ratio to clean):")
    for name, value in grabs.items():
        print(f"  {name:<12} {value:7.1f} ms   {value / grabs['clean']:5.2f} x clean")
    if args.baseline is not None:
        against_baseline(args.baseline.resolve(), config, args.frames, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
