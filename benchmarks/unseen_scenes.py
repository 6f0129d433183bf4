"""Lab scenes the estimator was never tuned on: bending sequences drawn by tests/scenes.py, not the twin.

    python benchmarks/unseen_scenes.py                 # 12 sequences of 12 frames, 6 conditions (about 5 min)
    python benchmarks/unseen_scenes.py --sequences 4   # a quicker pass
    python benchmarks/unseen_scenes.py --rows rows.csv # and every frame's outcome, with its reason

The twin's studies measure the estimator on the renderer its development ran against. This script
draws arms with another renderer (tests/scenes.py: its own rasteriser, the raw ZED-like pair with
distortion, a painted brick or plaster wall with wood, skin and a yellow cable beside the arm, and no
mount: the base is a free end) and varies what the twin's presets hold fixed. Each sequence is a
random arm bending smoothly from straight over its frames (curvature up to 5 /m per section in
random planes, a twist in the last, its base 0.75-1.5 m from the camera), seen in six conditions:

- lab: the wall (bricks or plaster) and the things beside the arm;
- dim: 30-55 % of the light, more sensor noise;
- warm: over-exposed warm light;
- blur: a horizontal pan of 5-13 px;
- occluded: a dark cable 8-25 mm wide crossing in front of the arm anywhere along it, at a slope;
- hand: a skin-coloured hand-sized object in front of the arm, from the fifth frame on.

Every condition is tracked from its first frame with the default ``EstimatorConfig()``. Prints, per
condition, the valid frames, those valid while more than 10 mm off (largest point or tip error, the
studies' false valid), the RMSE of the valid frames and each false valid frame. Some random arms
bend out of the picture: the valid frames are also counted among the frames whose whole tube lies
inside both images (``_in_view``), where a frame can be valid at all, so that the estimator's
refusals are told apart from the scene's. Seeded: the same
arguments draw the same scenes. Runs from a checkout (it reads tests/scenes.py beside it).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

SCENES_FILE = Path(__file__).resolve().parents[1] / "tests" / "scenes.py"
SECTIONS_M = (0.235, 0.23, 0.22)
CONDITIONS = ("lab", "dim", "warm", "blur", "occluded", "hand")
HAND_FROM = 4  # the hand comes in once the arm is tracked
FALSE_VALID_MM = 10.0
TUBE_RADIUS_M = 0.025  # tests/scenes.py's tube


@functools.cache
def _scenes():
    """tests/scenes.py, loaded from its file (the tests are not an installed package); registered
    under its own name while it runs, as its dataclasses look their module up."""
    spec = importlib.util.spec_from_file_location("unseen_scenes_renderer", SCENES_FILE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _along(points: np.ndarray, fraction: float) -> np.ndarray:
    """The point of a polyline this fraction of its length from its start."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return np.array([np.interp(fraction * arc[-1], arc, points[:, k]) for k in range(3)])


def _sequence(seed: int, frames: int, upto: int | None = None,
              through: str = CONDITIONS[-1]) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """One random arm bending over ``frames`` frames in every condition: condition -> [(left, right, truth)].

    ``upto`` (a frame) and ``through`` (a condition) draw only the frames and conditions up to them, the
    same as in the whole sequence (every random draw is made, in order; a test draws one frame of one
    condition without the rest)."""
    sc = _scenes()
    rng = np.random.default_rng(5000 + seed)
    curvature = rng.uniform(0.5, 5.0, 3)
    planes = rng.uniform(0.0, 2.0 * math.pi, 3)
    twist = rng.uniform(-1.0, 1.0)
    depth = rng.uniform(0.75, 1.5)
    base = (rng.uniform(-0.15, 0.15) * depth, -0.36 * depth, depth)
    tilt = rng.uniform(-0.15, 0.25)
    blur_px = int(rng.choice([5, 7, 9, 11, 13]))
    cable_at, cable_width, cable_slope = rng.uniform(0.15, 0.85), rng.uniform(0.008, 0.025), rng.uniform(-0.3, 0.3)
    hand_at = rng.uniform(0.2, 0.8)
    calib = sc.zed_like_calibration()
    names = CONDITIONS[:CONDITIONS.index(through) + 1]
    out: dict[str, list] = {c: [] for c in names}
    for f in range(frames if upto is None else upto + 1):
        bend = f / max(frames - 1, 1)
        sections = [sc.Section(SECTIONS_M[i], curvature[i] * bend, planes[i], twist * (i == 2)) for i in range(3)]
        points, joints = sc.backbone(sections, base, tilt_rad=tilt)
        # the cable and the hand lie in front of the arm's nearest point, drawn where they cross its line of sight
        near = float(points[:, 2].min())
        p, z = _along(points, cable_at), 0.7 * near
        x, y = p[0] * z / p[2], p[1] * z / p[2]
        cable = sc.cable_layer(z, np.array([[x - 1.0, y - cable_slope], [x + 1.0, y + cable_slope]]), cable_width,
                               sc.DARK_BGR)
        h, zh = _along(points, hand_at), 0.75 * near
        hand = sc.blob_layer(zh, (h[0] * zh / h[2] + 0.03, h[1] * zh / h[2]), (0.04, 0.06), sc.SKIN_BGR * 0.95)
        conditions = {"lab": sc.Lab(wall=("bricks", "plaster")[seed % 2]),
                      "dim": sc.Lab(light=float(rng.uniform(0.3, 0.55)), noise_std=float(rng.uniform(3.0, 4.5))),
                      "warm": sc.Lab(light=float(rng.uniform(1.05, 1.3)),
                                     tint_bgr=(float(rng.uniform(0.65, 0.8)), 0.95, float(rng.uniform(1.1, 1.2)))),
                      "blur": sc.Lab(motion_blur_px=blur_px),
                      "occluded": sc.Lab(extra=(cable,))}
        if f >= HAND_FROM:
            conditions["hand"] = sc.Lab(extra=(hand,))
        conditions = {name: lab for name, lab in conditions.items() if name in names}  # each keeps its seed
        rendered = sc.render_lab_scenes(calib, points, joints, conditions=conditions, seed=seed * 100 + f)
        rendered.setdefault("hand", rendered["lab"])
        for name in names:
            out[name].append((rendered[name].left, rendered[name].right, points))
    return out


def _in_view(calib, points: np.ndarray, radius_m: float = TUBE_RADIUS_M) -> bool:
    """Whether the tube round this backbone (left camera frame) lies wholly inside both raw images:
    each backbone point with its projected radius (at its depth) inside the picture."""
    width, height = calib.image_size
    for side in ("left", "right"):
        uv = calib.project(points, side)
        reach = calib.K(side)[0, 0] * radius_m / points[:, 2]
        if np.any((uv[:, 0] - reach < 0) | (uv[:, 0] + reach > width - 1)
                  | (uv[:, 1] - reach < 0) | (uv[:, 1] + reach > height - 1)):
            return False
    return True


def _run_sequence(args: tuple[int, int]) -> list[tuple[str, int, int, bool, float, float, str, bool]]:
    """Draw one sequence and track every condition: (condition, seed, frame, valid, rmse mm, worst mm,
    reason, whether the whole tube is in view)."""
    from estimator import CenterlineEstimator, EstimatorConfig
    from estimator.metrics import score_against_backbone

    seed, frames = args
    calib = _scenes().zed_like_calibration()
    rows = []
    for name, sequence in _sequence(seed, frames).items():
        estimator = CenterlineEstimator(calib, EstimatorConfig())
        for f, (left, right, truth) in enumerate(sequence):
            result = estimator.estimate(left, right)
            seen = _in_view(calib, truth)
            if result.valid:
                score = score_against_backbone(result.points, truth)
                worst = max(score["max_mm"], score.get("tip_mm", 0.0))
                rows.append((name, seed, f, True, score["rmse_mm"], worst, "", seen))
            else:
                rows.append((name, seed, f, False, math.nan, math.nan, result.reason, seen))
    return rows


def _write_rows(path: Path, rows: list[tuple]) -> None:
    """Every frame's outcome as CSV, one line per condition, seed and frame."""
    import csv

    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["condition", "seed", "frame", "valid", "rmse_mm", "worst_mm", "reason", "in_view"])
        for name, seed, frame, valid, rmse, worst, reason, seen in rows:
            writer.writerow([name, seed, frame, int(valid), f"{rmse:.3f}", f"{worst:.3f}", reason, int(seen)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=12, help="random arms (default 12)")
    parser.add_argument("--frames", type=int, default=12, help="frames per sequence (default 12)")
    parser.add_argument("--first-seed", type=int, default=10, help="seed of the first sequence (default 10)")
    parser.add_argument("--workers", type=int, default=2, help="sequences drawn and tracked at once (default 2)")
    parser.add_argument("--rows", type=Path, help="write every frame's outcome here (CSV: condition, seed, frame, "
                        "valid, rmse_mm, worst_mm, reason, in_view), to see what the refusals are")
    args = parser.parse_args(argv)
    jobs = [(args.first_seed + k, args.frames) for k in range(args.sequences)]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        rows = [row for rows in pool.map(_run_sequence, jobs) for row in rows]
    if args.rows is not None:
        _write_rows(args.rows, rows)
    print(f"Unseen lab scenes (tests/scenes.py): {args.sequences} sequences x {args.frames} frames, seeds "
          f"{args.first_seed}-{args.first_seed + args.sequences - 1}, default EstimatorConfig(), tracked\n")
    print(f"{'condition':<10} {'valid':>9} {'of in view':>16} {'false valid':>12} {'RMSE mm':>8}")
    for name in CONDITIONS:
        mine = [r for r in rows if r[0] == name]
        valid = [r for r in mine if r[3]]
        seen = [r for r in mine if r[7]]
        valid_seen = [r for r in seen if r[3]]
        wrong = [r for r in valid if r[5] > FALSE_VALID_MM]
        rmse = math.sqrt(sum(r[4] ** 2 for r in valid) / len(valid)) if valid else math.nan
        share = f"{len(valid_seen)}/{len(seen)} ({len(valid_seen) / max(len(seen), 1):.0%})"
        print(f"{name:<10} {len(valid):>4}/{len(mine):<4} {share:>16} {len(wrong):>12} {rmse:>8.2f}")
    outside = sum(1 for r in rows if r[0] == CONDITIONS[0] and not r[7])
    print(f"\n{outside} of the {len(rows) // len(CONDITIONS)} poses run partly out of view (same in every condition)")
    beyond = [r for r in rows if r[3] and not r[7]]
    if beyond:
        print(f"{len(beyond)} valid frame(s) with part of the tube out of view")
    wrong = [r for r in rows if r[3] and r[5] > FALSE_VALID_MM]
    if wrong:
        print("\nValid while more than 10 mm off:")
        for name, seed, f, _, rmse, worst, _, _ in wrong:
            print(f"  {name:<9} seed {seed:>3} frame {f:>2}: RMSE {rmse:.2f} mm, worst {worst:.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
