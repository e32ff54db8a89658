"""No silent phase on a terminal (issue 15): every command's long phases announce themselves and count their
steps on a terminal's stderr, and print nothing there when stderr is a pipe. Lines are asserted, not timings."""

import io
import shutil
import sys

import pytest

from uav_depth.cli.main import main
from uav_depth.cli.progress import Counted, Progress


class Tty(io.StringIO):
    def isatty(self):
        return True


def on_a_terminal(argv):
    """``uav-depth ARGV`` in this process with stderr a terminal: (exit code, the lines on stderr).
    (Swapped inside the test: pytest's capture puts its own stderr back between set-up and call.)"""
    saved, sys.stderr = sys.stderr, Tty()
    try:
        code = main([str(a) for a in argv])
        return code, sys.stderr.getvalue().splitlines()
    finally:
        sys.stderr = saved


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 3-frame 320x180 synthetic session, written through the CLI."""
    path = tmp_path_factory.mktemp("progress") / "s"
    assert main(["synth", str(path), "--frames", "3", "--width", "320", "--height", "180", "--focal-px", "175"]) == 0
    return path


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory):
    """A 4-frame 256x192 session and a base parameter file for it (as the tuner's tests use)."""
    from uav_depth.core.params import DEFAULT_PARAMS, save_params
    from uav_depth.sim.scene import SceneConfig, write_session

    root = tmp_path_factory.mktemp("tune")
    write_session(root / "s", 4, 5, SceneConfig(width=256, height=192, focal_px=160.0))
    save_params(DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 48}), root / "base.yaml")
    return root


def test_progress_prints_first_and_last_step_and_throttles_between():
    stream = Tty()
    p = Progress(stream, every_s=3600.0)
    p.phase("rendering 4 pairs")
    for i in range(1, 5):
        p.step("rendered", i, 4)
    assert stream.getvalue().splitlines() == ["rendering 4 pairs ...", "  rendered 1/4", "  rendered 4/4"]


def test_progress_is_silent_on_a_pipe_and_when_disabled():
    pipe = io.StringIO()
    for p in (Progress(pipe), Progress(Tty(), enabled=False)):
        p.phase("x")
        p.step("y", 1, 1)
        assert p.stream.getvalue() == ""
    assert pipe.getvalue() == ""


def test_counted_executor_counts_each_batch_and_passes_everything_through():
    class Executor:
        workers, kind = 3, "serial"

        def imap(self, tasks, stop=None):
            return iter(enumerate(t * 10 for t in tasks))

    stream = Tty()
    ex = Counted(Executor(), Progress(stream, every_s=0.0), "scored")
    assert list(ex.imap([1, 2])) == [(0, 10), (1, 20)] and list(ex.imap((3,))) == [(0, 30)]
    assert (ex.workers, ex.kind) == (3, "serial")
    assert stream.getvalue().splitlines() == ["  scored 1/2", "  scored 2/2", "  scored 1/1"]


def test_synth_announces_rendering_and_counts_pairs(tmp_path):
    code, lines = on_a_terminal(["synth", tmp_path / "s", "--frames", "2", "--width", "160", "--height", "96"])
    assert code == 0
    assert lines[0] == f"rendering 2 synthetic pairs 160x96 into {tmp_path / 's'} ..."
    assert lines[1:] == ["  rendered 1/2", "  rendered 2/2"]


def test_synth_prints_no_progress_on_a_pipe(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "s"), "--frames", "2", "--width", "160", "--height", "96"]) == 0
    assert capsys.readouterr().err == ""


def test_bench_announces_rendering_and_timing_and_counts_frames():
    code, lines = on_a_terminal(["bench", "--frames", "2", "--rounds", "2", "--naive-rounds", "1", "--width", "160",
                                 "--height", "96"])
    assert code == 0
    assert lines[:3] == ["rendering 2 synthetic pairs 160x96 ...", "  rendered 1/2", "  rendered 2/2"]
    assert lines[3] == "timing 4 pipelines interleaved, 2 round(s) over 2 frames ..."
    # every round says its first frame; the last frame of the last round is always said
    assert "  round 1/2, frames timed 1/4" in lines and "  round 2/2, frames timed 3/4" in lines
    assert lines[-1] == "  round 2/2, frames timed 4/4"


def test_bench_json_prints_no_progress():
    assert on_a_terminal(["bench", "--frames", "1", "--rounds", "1", "--naive-rounds", "1", "--width", "160",
                          "--height", "96", "--json"]) == (0, [])


def test_check_rig_announces_matching_and_counts_frames(session):
    _, lines = on_a_terminal(["check-rig", session, "--frames", "5"])      # the verdict is not the point here
    assert lines[0] == f"matching features in 3 frame(s) of {session} ..."
    assert lines[1] == "  frames matched 1/3" and lines[-1] == "  frames matched 3/3"


def test_evaluate_announces_loading_and_scoring_and_counts_frames(session):
    code, lines = on_a_terminal(["evaluate", session, "--set", "sgbm.num_disparities=64"])
    assert code == 0
    assert lines[0] == f"loading 3 frame(s) from {session} ..."
    assert lines[1] == "  frames loaded 1/3" and lines[2] == "  frames loaded 3/3"
    assert lines[3].startswith("scoring parameters ") and lines[3].endswith(" on 3 frame(s) ...")
    assert lines[4:] == ["  frames scored 1/3", "  frames scored 3/3"]


def test_evaluate_one_frame_at_a_time_scores_as_the_whole_set(session, capsys):
    """Scoring frame by frame (for the progress lines) gives the figures of one evaluation of the whole set."""
    import json
    import math

    from uav_depth.core.params import DEFAULT_PARAMS
    from uav_depth.core.session import iter_frames
    from uav_depth.tuning.frames import FrameSet, load_frame
    from uav_depth.tuning.metrics import METRIC_NAMES
    from uav_depth.tuning.objective import FITNESS, evaluate

    assert main(["evaluate", str(session), "--set", "sgbm.num_disparities=64", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    params = DEFAULT_PARAMS.replace(**{"sgbm.num_disparities": 64})
    frames = FrameSet("all", tuple(load_frame(r) for r in iter_frames(session, require_reference=True)))
    whole = evaluate(params, frames, FITNESS["flown"], full=True, convention="bench")
    assert [f["id"] for f in doc["frames"]] == frames.keys
    for name in METRIC_NAMES["bench"]:
        assert doc["mean"][name] == pytest.approx(whole.metrics[name], rel=1e-9)
        for row, ref in zip(doc["frames"], whole.frame_metrics):
            assert row[name] == pytest.approx(ref[name], rel=1e-9)
    for row, ref in zip(doc["frames"], whole.frame_metrics):
        branch = ref.get("branch_m")
        assert row["branch_m"] == (None if branch is None or not math.isfinite(branch) else pytest.approx(branch))


def test_session_import_announces_checking_and_writing_and_counts_pairs(session, tmp_path):
    src = tmp_path / "pairs"
    src.mkdir()
    for rec in sorted((session / "frames").glob("*_left.png")):
        stem = rec.name[: -len("_left.png")]
        for side in ("left", "right"):
            shutil.copy(session / "frames" / f"{stem}_{side}.png", src / f"{stem}_{side}.png")
    out = tmp_path / "imported"
    code, lines = on_a_terminal(["session", "import", src, out, "--focal-px", "175", "--baseline-m", "0.063"])
    assert code == 0
    assert lines == [f"checking 3 pairs 320x180 in {src} (nothing is written before) ...", "  pairs checked 1/3",
                     "  pairs checked 3/3", f"writing 3 pairs into {out} ...", "  pairs written 1/3",
                     "  pairs written 3/3"]


def test_demo_says_what_it_renders_and_counts_pairs(tmp_path, capsys):
    assert on_a_terminal(["demo", "--out", tmp_path / "d", "--frames", "1"]) == (0, ["  rendered 1/1"])
    assert capsys.readouterr().out.splitlines()[0] == f"rendering 1 synthetic pairs 1280x720 into {tmp_path / 'd'} ..."


def test_tune_announces_every_phase_after_its_bar(tiny_session, tmp_path):
    """What runs after the progress bar (choosing on the validation frames, full scores, the safety sweep, the
    report) says so, and the safety sweep counts the frames it renders and reads."""
    rep = tmp_path / "rep"
    code, lines = on_a_terminal(["tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer",
                                 "random", "--population", "2", "--generations", "1", "--holdout", "0.5",
                                 "--workers", "1", "--store", tmp_path / "store.sqlite", "--report", rep,
                                 "--safety-sweep", "quick", "--sweep-cache", tmp_path / "cache", "--force"])
    assert code == 0
    phases = [line for line in lines if line.endswith(" ...") and "|" not in line]
    # each evaluation after the bar is counted: the choice, then base and chosen on every frame set
    assert any(line.startswith("  candidates scored 1/") for line in lines)
    assert "  scored 1/6" in lines and "  scored 6/6" in lines
    assert phases[:4] == ["loading the tuner ...",
                          "ranging every candidate with the default ranging settings (no config file) ...",
                          f"loading the frames of {tiny_session / 's'} ...",
                          "1 training, 2 validation and 1 test frame(s): the search trains, the choice chooses, the "
                          "gate judges on the test frames alone ..."]
    assert phases[4] == "choosing among the best candidates on the 2 validation frame(s) ..."
    assert phases[5] == "scoring the base and the chosen parameters with every metric on train, validation, test ..."
    assert phases[-1] == f"writing the report and its plots into {rep} ..."
    if any(p.startswith("the safety sweep: ") for p in phases):     # the chosen beat the base on its frames
        assert any(p.startswith("rendering the safety sweep at 256x192") for p in phases)
        assert "  safety sweep: frames rendered 84/84" in lines
        assert "  safety sweep: the base, frames read 84/84" in lines


def test_tune_no_progress_silences_its_phases(tiny_session, tmp_path):
    _, lines = on_a_terminal(["tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer",
                              "random", "--population", "2", "--generations", "1", "--holdout", "none", "--workers",
                              "1", "--store", tmp_path / "store.sqlite", "--no-progress", "--safety-sweep", "quick",
                              "--sweep-cache", tmp_path / "cache"])
    assert [line for line in lines if line.endswith(" ...")] == []
