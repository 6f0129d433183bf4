"""The report's paper-mode parts (issue 12): Fig 12's compensation variants, Fig 13's numpy-SOM speed,
Table 2 computed the paper's way, and the count of frames each plausibility check flagged."""

import json

import numpy as np
import pytest

from bench.config import load_bench_config
from bench.recording import load_run
from bench.report import CHECKS, write_report
from bench.run import RunOptions, run_experiment

FRAMES = 6


@pytest.fixture(scope="module")
def paper_report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper") / "run"
    outcome = run_experiment(load_bench_config(), RunOptions(mode="paper", frames=FRAMES, out=folder, progress=False,
                                                             report=False))
    assert outcome.exit_code == 0
    report = write_report(folder, options={"video": False, "compensation_frames": FRAMES})
    return folder, report


def test_paper_mode_records_every_frame_with_its_flags(paper_report):
    folder, _ = paper_report
    run = load_run(folder)
    assert len(run.frames) == FRAMES and all(f.main.valid for f in run.frames)  # the paper reports every frame
    assert all(isinstance(f.main.flags, tuple) and set(f.main.flags) <= set(CHECKS) for f in run.frames)
    lines = [json.loads(line) for line in (folder / "frames.jsonl").read_text().splitlines()]
    assert all(isinstance(line["flags"], list) and set(line["flags"]) <= set(CHECKS) for line in lines)


def test_the_report_reruns_the_variants_and_computes_table_2_the_papers_way(paper_report):
    _, report = paper_report
    compensation = json.loads((report / "compensation.json").read_text())
    assert set(compensation["summary"]) == {"nearest", "nearest_image", "none", "numpy"}
    nearest = compensation["summary"]["nearest"]
    assert nearest["valid_frames"] == FRAMES and set(nearest["flagged"]) == set(CHECKS)
    # Table 2 from the unsmoothed Q: the surface depth sits about a radius (25 mm) in front of the axis;
    # at rest (t = 0) the z column against the surface is that offset, against the axis a few mm
    surface, axis = nearest["table2_surface_xyz_mm"], nearest["table2_axis_xyz_mm"]
    assert all(np.isfinite(surface)) and all(np.isfinite(axis))
    at_rest = compensation["nearest"][0]["table2"]
    assert at_rest["surface"]["count"] == at_rest["axis"]["count"] == 20
    assert at_rest["surface"]["z_mm"] == pytest.approx(25.0, abs=5.0) and at_rest["axis"]["z_mm"] < 6.0
    # the numpy SOM gives the compiled SOM's estimates (to rounding), slower
    numpy = compensation["summary"]["numpy"]
    assert numpy["rmse_mm"] == pytest.approx(nearest["rmse_mm"], abs=0.01)
    # which SOM each variant ran, from the report's own record (how fast each is: benchmarks/estimator_speed.py)
    assert compensation["variants"]["numpy"]["som_compiled"] is False
    assert compensation["variants"]["nearest"].get("som_compiled", True) is True
    assert np.isfinite(numpy["fps"]) and numpy["fps"] > 0
    text = (report / "summary.md").read_text()
    for heading in ("## Plausibility checks", "## Misalignment compensation (Fig 12)",
                    "## Table 2 computed the paper's way", "## Paper mode speed (Fig 13)"):
        assert heading in text, heading
    assert "| axis depth |" in text and "| numpy SOM (the paper's speed class) |" in text
    # eq. (11) is read off the SOM's nodes, the same in every variant: said once, not as a column of equal figures
    assert compensation["summary"]["nearest"]["misalignment_px"] == compensation["summary"]["none"]["misalignment_px"]
    assert text.count("Misalignment eq. (11) between the SOM's left and right nodes before compensation") == 1
    assert "misalignment eq. (11) (px) |" not in text
