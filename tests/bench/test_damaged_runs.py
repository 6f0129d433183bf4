"""`softarm report` and `softarm replay` on damaged run folders: partial and malformed records, repeated
indices, a cut last line, summary.json or config.json that are not JSON objects. Each gives a report that
names what it skipped and agrees with what it read, or a clear message and exit code 2; never a traceback."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from bench.config import RecordingConfig
from bench.recording import CONFIG_FILE, FRAMES_FILE, SUMMARY_FILE, RunWriter, load_run, summarize_run
from bench.replay import replay_command
from bench.report import report_command
from tests.bench.test_recording import frame_record, noisy_pair
from tests.fakes import small_calibration

CONFIG = {"backend": "sim", "estimators": {"main": {"mode": "default"}},
          "bench": {"report": {"video": False, "compensation_frames": 0, "selected_frames": 3}}}


@pytest.fixture
def finished_run(tmp_path):
    """A finished run of 10 frames (frame 2 invalid) with its images, calibration and a true summary."""
    folder = tmp_path / "run"
    writer = RunWriter(folder, RecordingConfig(), config=CONFIG, calibration=small_calibration())
    records = [frame_record(i, 1.0 + i, valid=i != 2) for i in range(10)]
    for record in records:
        writer.submit(dict(record), *noisy_pair(record["index"]))
    writer.finish(summarize_run(records, CONFIG))
    return folder


def report(folder, capsys) -> tuple[int, str, str]:
    code = report_command(SimpleNamespace(run_dir=str(folder)))
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    text = (folder / "report" / "summary.md").read_text() if code == 0 else ""
    return code, text, captured.err


def append(folder, line: str) -> None:
    with open(folder / FRAMES_FILE, "a") as f:
        f.write(line + "\n")


@pytest.mark.parametrize(("bad", "why"), [
    ('{"index": 10}', "missing key 't_s'"),  # the reported KeyError: 't_s'
    (json.dumps({**frame_record(10, 1.0), "points_m": "x"}), "points_m: expected a list of [x, y, z], got 'x'"),
    (json.dumps({**frame_record(10, 1.0), "commanded_bar": {"s1_a": "high"}}),
     "commanded_bar: s1_a: expected a number, got 'high'"),
])
def test_a_bad_record_appended_is_skipped_and_named_in_the_report(finished_run, capsys, bad, why):
    append(finished_run, bad)
    code, text, err = report(finished_run, capsys)
    assert code == 0, err
    assert "frames recorded: 10, valid: 9" in text
    assert f"1 line of frames.jsonl skipped (line 11: not a frame record: {why}" in text
    assert f"line 11: not a frame record: {why}" in err  # said while the report is written, too


def test_a_repeated_index_keeps_the_first_record(finished_run, capsys):
    append(finished_run, json.dumps(frame_record(3, 99.0)))
    code, text, _ = report(finished_run, capsys)
    assert code == 0
    run = load_run(finished_run)
    assert [f.index for f in run.frames] == list(range(10)) and run.frames[3].main.errors["rmse_mm"] == 4.0
    assert "line 11: index 3 again (first on line 4); the first is kept" in text
    assert "frames recorded: 10, valid: 9" in text and "disagreed" not in text


def test_a_cut_last_line_makes_the_summary_agree_with_the_frames_read(finished_run, capsys):
    """The reported case: the last line cut, and the report said "frames recorded: 9, valid: 10"."""
    path = finished_run / FRAMES_FILE
    path.write_bytes(path.read_bytes()[:-50])  # the last record loses its end (and its end of line)
    code, text, _ = report(finished_run, capsys)
    assert code == 0
    assert "frames recorded: 9, valid: 8" in text
    assert "line 10: cut short (no end of line: the run was killed while writing it)" in text
    assert "summary.json disagreed with the 9 frames read (frames 10 there, 9 in the frames, valid_frames 9 there, " \
           "8 in the frames" in text and "recomputed from the frames" in text
    run = load_run(finished_run)
    assert run.complete and run.summary["frames"] == 9 and run.summary["valid_frames"] == 8


@pytest.mark.parametrize("content", ["[1, 2, 3]", '"done"', "null"])
def test_a_summary_that_is_not_an_object_is_recomputed(finished_run, capsys, content):
    (finished_run / SUMMARY_FILE).write_text(content)
    code, text, _ = report(finished_run, capsys)
    assert code == 0
    assert "summary.json is not a JSON object" in text and "recomputed from the frames" in text
    assert "frames recorded: 10, valid: 9" in text


def test_a_missing_image_file_is_named_by_replay_and_report(finished_run, tmp_path, capsys):
    """The reported case: frame 5's left image deleted, and replay said "replayed 9 frames" without
    naming it, the report only OpenCV's own warning."""
    name = load_run(finished_run).frames[5].images["left"]
    (finished_run / name).unlink()
    assert load_run(finished_run).image_problems() == [f"frame 5: {name} is missing"]
    out = tmp_path / "replayed"
    args = SimpleNamespace(run_dir=str(finished_run), mode=None, centerline=None, out=str(out))
    assert replay_command(args) == 0
    err = capsys.readouterr().err
    assert f"left out 1 frame whose images cannot be read (frame 5: {name} is missing)" in err
    summary = json.loads((out / SUMMARY_FILE).read_text())
    assert summary["frames"] == 9 and summary["skipped"] == [f"frame 5: {name} is missing"]
    assert [f.index for f in load_run(out).frames] == [0, 1, 2, 3, 4, 6, 7, 8, 9]
    code, text, _ = report(finished_run, capsys)
    assert code == 0
    assert f"left out of the images and the video: 1 frame whose images cannot be read (frame 5: {name} is " \
           "missing)" in text


def test_a_config_that_is_not_an_object_is_a_clear_error_for_report_and_replay(finished_run, capsys):
    (finished_run / CONFIG_FILE).write_text("[1, 2, 3]")
    code, _, err = report(finished_run, capsys)
    assert code == 2
    assert f"{finished_run / CONFIG_FILE}: expected a JSON object (the run's configuration), got a list" in err
    args = SimpleNamespace(run_dir=str(finished_run), mode=None, centerline=None, out=None)
    assert replay_command(args) == 2
    assert "expected a JSON object" in capsys.readouterr().err


def test_bad_recorded_report_options_are_named_not_a_traceback(finished_run, capsys):
    config = json.loads((finished_run / CONFIG_FILE).read_text())
    config["bench"]["report"]["video_scale"] = "half"
    (finished_run / CONFIG_FILE).write_text(json.dumps(config))
    code, _, err = report(finished_run, capsys)
    assert code == 2
    assert "[bench.report] video_scale: expected a number, got 'half'" in err


def test_report_and_replay_answer_a_folder_that_is_not_a_run_alike(tmp_path, capsys):
    """Both exit 2 (documented in their --help): the RUN argument is not a run folder."""
    args = SimpleNamespace(run_dir=str(tmp_path), mode=None, centerline=None, out=None)
    assert report_command(args) == 2
    assert replay_command(args) == 2
    err = capsys.readouterr().err
    assert err.count("not a run folder (no frames.jsonl)") == 2
    # a folder that is not there, a file, and the default RUN before any run: each said as what it is
    (tmp_path / "a_file").write_text("")
    for run_dir, said in ((tmp_path / "gone", "gone: no such folder"),
                          (tmp_path / "a_file", "a file, not a run folder"),
                          (tmp_path / "runs" / "latest", "no run yet under")):
        args = SimpleNamespace(run_dir=str(run_dir), mode=None, centerline=None, out=None)
        assert report_command(args) == 2 and replay_command(args) == 2
        assert capsys.readouterr().err.count(said) == 2
    from bench.cli import build_parser

    for command in ("report", "replay"):
        text = build_parser()._subparsers._group_actions[0].choices[command].format_help()
        assert "2 RUN is not a readable run folder" in text


def test_invalid_reasons_with_measurements_are_grouped(finished_run, capsys):
    records = [frame_record(i, 1.0, valid=False) for i in range(3)]
    for record, length in zip(records, (1402, 1390, 1511), strict=True):
        record["reason"] = f"implausible estimate: {length} mm long for a 680 mm arm"
    summary = summarize_run(records, CONFIG)
    assert summary["invalid_reasons"] == {"implausible estimate: # mm long for a # mm arm": 3}
    assert summary["invalid_examples"] == {
        "implausible estimate: # mm long for a # mm arm": "implausible estimate: 1402 mm long for a 680 mm arm"}
    path = finished_run / FRAMES_FILE
    path.write_text("".join(json.dumps({**r, "index": 10 + i}) + "\n" for i, r in enumerate(records)), )
    (finished_run / SUMMARY_FILE).unlink()
    code, text, _ = report(finished_run, capsys)
    assert code == 0
    assert '- 3 x implausible estimate: # mm long for a # mm arm (e.g. "implausible estimate: 1402 mm long for a ' \
           '680 mm arm")' in text


def test_the_report_figures_label_log_axes_with_plain_numbers(finished_run, monkeypatch):
    """Fig 12 and Fig 13 have log axes; their labels read 20, not 2x10^1."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from bench.report import write_report

    labels: dict[str, list[str]] = {}
    original = Figure.savefig

    def record(self, path, *args, **kwargs):
        self.canvas.draw()
        for ax in self.axes:
            if ax.get_yscale() == "log":
                texts = [t.get_text() for t in ax.get_yticklabels() + ax.get_yticklabels(minor=True)]
                labels.setdefault(str(path).rsplit("/", 1)[-1], []).extend(t for t in texts if t)
        return original(self, path, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    write_report(finished_run)
    assert set(labels) >= {"fig12_axis_error.png", "fig13_fps.png"}
    for name, texts in labels.items():
        assert texts, name
        for text in texts:
            assert all(c in "0123456789.−-" for c in text), (name, text)  # plain numbers: no 10^, no e+01


def test_the_video_caption_sits_on_its_own_opaque_box():
    """Text and background are drawn from one anchor at one thickness: every pixel the caption changes is
    inside its box, the box is opaque (no frame shows through) and the text is readable white on black."""
    from bench.report import draw_caption

    green = (30, 200, 90)  # a colour anti-aliased white-on-black text never produces
    frame = np.full((120, 320, 3), green, np.uint8)
    x0, y0, x1, y1 = draw_caption(frame, ("t  12.3 s  s1_a 1.25 s2_a 1.25", "rmse 3.4 mm"))
    changed = np.any(frame != green, axis=2)
    ys, xs = np.nonzero(changed)
    assert xs.min() >= x0 and xs.max() <= x1 and ys.min() >= y0 and ys.max() <= y1  # nothing outside the box
    box = frame[y0:y1 + 1, x0:x1 + 1]
    assert not np.any(np.all(box == green, axis=2))  # opaque: no frame pixel shows through
    assert np.all(box.max(axis=2) - box.min(axis=2) <= 1)  # grey levels only: text and box drawn aligned
    assert (box.max(axis=2) > 200).sum() > 100 and (box.max(axis=2) < 30).mean() > 0.5  # white text on black
    assert x1 - x0 < 320 and y1 - y0 < 60  # a caption, not the whole frame
