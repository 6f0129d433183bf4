"""The ``softarm`` command line: one entry point, one subcommand per job.

Each subcommand's implementation is imported only when it runs, so ``softarm rig check``
never loads MuJoCo and ``softarm --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand -> (module, function); the function takes the parsed arguments, returns an exit code.
_HANDLERS = {
    "run": ("bench.run", "run_command"),
    "report": ("bench.report", "report_command"),
    "replay": ("bench.replay", "replay_command"),
    "view": ("bench.live_view", "view_command"),
    "study": ("bench.studies", "study_command"),
    "calibrate": ("bench.calibrate", "calibrate_command"),
    "rig": ("bench.rig_check", "rig_command"),
}


# bench.recording's EXIT_* codes (not imported here: `softarm --help` stays fast)
_RUN_EXIT_CODES = "exit status: 0 done; 1 failed while writing; 2 RUN is not a readable run folder"
# The newest run, which report and replay take when RUN is left out (bench.recording.LATEST under runs/).
_LATEST_RUN = "runs/latest"


def version() -> str:
    """The installed softarm-twin's version ("unknown" when it runs from a folder without being installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("softarm-twin")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="softarm",
        description="Stereo centerline estimation of a three-section soft arm, on its digital twin or the rig.",
        epilog="Example: softarm run --frames 60   (a quick run of the paper's bending experiment on the twin)",
    )
    parser.add_argument("--version", action="version", version=f"softarm {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(name: str, help_: str, example: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=help_, description=f"Example: {example}\n\n{help_}",
                              formatter_class=argparse.RawDescriptionHelpFormatter)

    run = add("run", "Run an experiment: drive the valves, estimate every frame, score and record.",
              "softarm run --frames 60 --out runs/quick")
    run.add_argument("--config", help="bench config (TOML); default models/bench.toml")
    run.add_argument("--backend", choices=("sim", "rig"), help="override the config's backend")
    run.add_argument("--mode", choices=("default", "paper"), help="estimator mode (overrides the config)")
    run.add_argument("--compare", action="store_true", help="also run the paper mode on every frame and compare")
    run.add_argument("--frames", type=int, help="spread N frames over the whole experiment (quick, coarse run)")
    run.add_argument("--out", help="run folder; default runs/<timestamp> under the working directory (runs/latest "
                     "points to it)")
    run.add_argument("--no-report", action="store_true", help="skip the plots and video at the end")
    run.add_argument("--yes", action="store_true",
                     help="go ahead with a run expected to write more than 2 GB (the expected size is printed first)")
    run.add_argument("--view", nargs="?", const="native", choices=("native", "web"), metavar="web",
                     help="watch it live in Rerun: --view spawns the viewer (needs a display), --view web serves the "
                     "web viewer and prints its URL (needs: pip install 'softarm-twin[view]')")
    run.add_argument("--rrd", metavar="FILE", help="save the Rerun recording to FILE (with or without --view)")

    report = add("report", "Write plots, overlay video and a markdown summary for a run folder.",
                 "softarm report runs/2026-11-22_101500")
    report.epilog = _RUN_EXIT_CODES
    report.add_argument("run_dir", metavar="RUN", nargs="?", default=_LATEST_RUN,
                        help=f"the run folder; default {_LATEST_RUN} (the newest run under the working directory)")

    replay = add("replay", "Re-run an estimator configuration on a recorded run and score it again.",
                 "softarm replay runs/2026-11-22_101500 --mode paper")
    replay.epilog = _RUN_EXIT_CODES
    replay.add_argument("run_dir", metavar="RUN", nargs="?", default=_LATEST_RUN,
                        help=f"the run folder; default {_LATEST_RUN} (the newest run under the working directory)")
    replay.add_argument("--mode", choices=("default", "paper"))
    replay.add_argument("--centerline", choices=("som", "competitive", "kmeans++", "thinning", "skeleton"),
                        help="2D centerline stage to use")
    replay.add_argument("--out", help="output folder; default runs/replay_<timestamp> under the working directory "
                        "(runs/latest then points to it)")

    study = add("study", "Run a study on the twin: the paper's SOM study or centerline comparison, robustness in lab "
                "scenes, a parameter sweep or the accuracy along the arm; on this machine or on Ray.",
                "softarm study robustness --frames 60 --workers 2   (or: som, compare, sweep --grid FILE, accuracy)")
    study.add_argument("which", choices=("som", "compare", "robustness", "sweep", "accuracy"))
    study.add_argument("--config", help="bench config (TOML); default models/bench.toml")
    study.add_argument("--frames", type=int, help="twin frames to study (robustness: per condition)")
    study.add_argument("--out", help="output folder; default runs/study_<which>_<timestamp> under the working "
                       "directory")
    study.add_argument("--conditions", nargs="+", metavar="PRESET[:SEED]",
                       help="robustness: scene presets to run (default: clean lab dim bright_warm blur occluded "
                       "random)")
    study.add_argument("--grid", metavar="FILE.toml", help="sweep: the parameters and scenes to sweep")
    study.add_argument("--engine", choices=("local", "ray"), default="local",
                       help="where episodes run: a process pool here (default) or Ray tasks")
    study.add_argument("--workers", type=int, help="episodes at once (default: every CPU here, or of the Ray cluster)")
    study.add_argument("--ray-address", metavar="HOST:PORT", help="the Ray cluster to use (with --engine ray); "
                       "default: a local Ray started for the study")

    calibrate = add("calibrate", "Calibrate the stereo camera from checkerboard views and write a calibration file.",
                    "softarm calibrate --out calib.toml")
    calibrate.add_argument("--config", help="bench config (TOML); default models/bench.toml")
    calibrate.add_argument("--backend", choices=("sim", "rig"), help="override the config's backend")
    calibrate.add_argument("--out", help="calibration file to write (TOML); default runs/calibration_<timestamp>.toml "
                           "under the working directory")
    calibrate.add_argument("--views", type=int, help="number of board views to use; default 15 on the twin, 20 on "
                           "the rig")
    calibrate.add_argument("--board", metavar="COLSxROWS", help="inner corners of the checkerboard; default 9x6")
    calibrate.add_argument("--square-mm", type=float, help="printed square size in mm; default 40")

    view = add("view", "Turn a recorded run into the Rerun recording `run --view` shows: open, serve or save it.",
               "softarm view runs/latest --rrd run.rrd   (then: rerun run.rrd)")
    view.epilog = _RUN_EXIT_CODES.replace("1 failed while writing", "1 the view failed")
    view.add_argument("run_dir", metavar="RUN", nargs="?", default=_LATEST_RUN,
                      help=f"the run folder; default {_LATEST_RUN} (the newest run under the working directory)")
    view.add_argument("--rrd", metavar="FILE", help="save the recording to FILE instead of opening the viewer")
    view.add_argument("--web", action="store_true", help="serve the web viewer and print its URL (Ctrl-C stops it)")

    rig = add("rig", "Check the physical rig's devices without moving anything.", "softarm rig check")
    rig.add_argument("action", choices=("check",))
    rig.add_argument("--config", help="bench config (TOML); default models/bench.toml")
    return parser


# study options that only one study takes: option -> (flag, that study)
_ONE_STUDY_OPTIONS = {"conditions": ("--conditions", "robustness"), "grid": ("--grid", "sweep")}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "study":
        for key, (flag, owner) in _ONE_STUDY_OPTIONS.items():
            if getattr(args, key, None) is not None and args.which != owner:
                # said, not ignored: a study run without the option the user meant to vary misleads
                parser.error(f"{flag} is an option of the {owner} study; study {args.which} does not take it")
    module_name, function_name = _HANDLERS[args.command]
    module = importlib.import_module(module_name)
    return int(getattr(module, function_name)(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
