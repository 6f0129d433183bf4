"""Estimator speed: per-stage milliseconds and fps for the default mode (in the clean scene and in
the lab scene), the paper mode with the compiled SOM and the paper mode with the numpy reference
SOM, measured side by side in one run.

Frames come from the digital twin along the paper's ramp (s1_a, s2_a, s3 from 0 to 2.5 bar), so
the arm takes the shapes of the experiment; the lab column renders the same ramp in the ``lab``
scene preset (brick wall, wood, skin, cables, two lights), the blur column in the ``blur`` preset
(the lab with a 9 px camera shake: the blur is measured and taken out, stages ``blur`` and
``deblur``). Those frames are 58 s / ``--frames`` apart, so the arm moves far between them (a hard
case for the warm start: its second tube-fit start and its cold searches run often). The "lab
scene, 30 fps stream" column is what a live camera hands over: frames 1/30 s apart from t = 29 s of
the ramp on. Each configuration runs its whole sequence with warm start, interleaved frame by frame
so machine load affects all of them alike; medians are quoted.

    python benchmarks/estimator_speed.py [--frames 30] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.som import linear_init, som_online

RAMP_S = 58.0
STREAM = (29.0, 1.0 / 30.0)  # a live stream: from this time of the ramp, frames this far apart
# column -> (scene preset, frame spacing: None along the whole ramp, else STREAM, estimator configuration)
CONFIGS = {
    "default": ("clean", None, EstimatorConfig()),
    "default, lab scene": ("lab", None, EstimatorConfig()),
    "lab scene, 30 fps stream": ("lab", STREAM, EstimatorConfig()),
    "default, blur scene": ("blur", None, EstimatorConfig()),
    "paper (compiled SOM)": ("clean", None, EstimatorConfig(mode="paper")),
    "paper (numpy SOM)": ("clean", None, EstimatorConfig(mode="paper", som_compiled=False)),
}


def twin_frames(count: int, preset: str, stream: tuple[float, float] | None = None):
    import dataclasses

    from twin import Twin
    from twin.twin import DEFAULT_CONFIG, TwinConfig

    twin = Twin(dataclasses.replace(TwinConfig.load(DEFAULT_CONFIG), scene_preset=preset))

    def ramp_to(t_s: float) -> None:
        pressure = 2.5 * min(t_s / RAMP_S, 1.0)
        twin.valves.set_pressures({"s1_a": pressure, "s2_a": pressure, "s3": pressure})

    frames = []
    if stream is not None:
        start_s, interval_s = stream
        for t_s in np.arange(0.5, start_s, 0.5):  # the ramp up to the stream's start
            ramp_to(t_s)
            twin.advance(0.5)
    for i in range(count):
        if stream is None:
            ramp_to(RAMP_S * i / max(count - 1, 1))
            twin.advance(RAMP_S / count)
        else:
            ramp_to(stream[0] + i * stream[1])
            twin.advance(stream[1])
        frame = twin.camera.grab()
        frames.append((frame.left, frame.right))
    calibration = twin.camera.calibration
    twin.close()
    return calibration, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--frames", type=int, default=30,
                        help="twin frames along the ramp per configuration (58 s / frames apart; default 30)")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the frames (default 3)")
    args = parser.parse_args()

    scenes = {}
    for key in dict.fromkeys((preset, stream) for preset, stream, _ in CONFIGS.values()):
        scenes[key] = twin_frames(args.frames, *key)
    calibration = next(iter(scenes.values()))[0]
    estimators = {name: CenterlineEstimator(calibration, cfg) for name, (_, _, cfg) in CONFIGS.items()}
    frames_of = {name: scenes[preset, stream][1] for name, (preset, stream, _) in CONFIGS.items()}
    for name, est in estimators.items():  # compile and warm caches outside the timing
        est.estimate(*frames_of[name][0])
        est.reset()

    stages: dict[str, dict[str, list[float]]] = {name: {} for name in estimators}
    cold: dict[str, list[float]] = {name: [] for name in estimators}
    for _ in range(args.repeats):
        for est in estimators.values():
            est.reset()
        for i in range(args.frames):
            for name, est in estimators.items():
                result = est.estimate(*frames_of[name][i])
                for stage, ms in result.timings_ms.items():
                    stages[name].setdefault(stage, []).append(ms)
    for i in range(0, args.frames, max(1, args.frames // 10)):
        for name, est in estimators.items():
            est.reset()
            cold[name].append(est.estimate(*frames_of[name][i]).timings_ms["total"])

    order = ["locate", "rectify", "deblur", "segment", "centerline", "refine", "edges", "blur", "match",
             "triangulate", "smooth", "tube", "output", "total"]
    print(f"Estimator speed, {args.frames} twin frames (1280x720 stereo pairs) x {args.repeats}, medians in ms")
    print("(stage times add both images, which run in parallel; 'total' is wall time per pair)\n")
    print(f"{'stage':<12}" + "".join(f"{name:>26}" for name in estimators))
    for stage in order:
        row = [statistics.median(stages[name].get(stage, [0.0])) for name in estimators]
        print(f"{stage:<12}" + "".join(f"{v:>26.2f}" for v in row))
    totals = {name: statistics.median(stages[name]["total"]) for name in estimators}
    print(f"{'fps (warm)':<12}" + "".join(f"{1000.0 / totals[name]:>26.1f}" for name in estimators))
    print(f"{'cold total':<12}" + "".join(f"{statistics.median(cold[name]):>26.2f}" for name in estimators))
    base = totals["default"]
    print("\nRatios of wall time per pair (same run):")
    for name in estimators:
        print(f"  {name:<24} {totals[name] / base:6.2f} x default")

    # The SOM alone as the paper preset runs it (Table 1: n=20, N=2, alpha0=0.2, lambda=15; its clock and
    # the contour's own order) on a contour-sized input.
    paper = EstimatorConfig(mode="paper")
    rng = np.random.default_rng(0)
    s = np.linspace(0, 1, 300)
    points = np.column_stack([800 + 60 * np.sin(3 * s), 250 + 450 * s]) + rng.normal(0, 8, (300, 2))
    init = linear_init(points, paper.n_points)
    timing = {}
    for compiled in (True, False):
        def train(compiled=compiled):
            return som_online(points, init, epochs=paper.som_epochs, alpha0=paper.som_alpha0,
                              lam=float(paper.som_epochs), radius=paper.som_radius, sigma0=paper.som_sigma,
                              time=paper.som_time, order=paper.som_order, shrink=paper.som_shrink, compiled=compiled)
        train()
        samples = []
        for _ in range(15 if compiled else 5):
            start = time.perf_counter()
            train()
            samples.append((time.perf_counter() - start) * 1e3)
        timing[compiled] = statistics.median(samples)
    print(f"\nSOM alone, as the paper preset runs it ({len(points)} contour points, {paper.som_epochs} epochs, "
          f"t per {paper.som_time}, {paper.som_order} order): compiled {timing[True]:.2f} ms, "
          f"numpy reference {timing[False]:.1f} ms ({timing[False] / timing[True]:.0f}x)")


if __name__ == "__main__":
    main()
