"""uav-depth tune as a user runs it: real subprocesses, real files, a real kill and a real Ctrl-C."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from uav_depth.cli.main import EXIT_CONFIG
from uav_depth.core.params import load_params, read_provenance


def cli(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(proc.stderr)
    return proc


def _args(root, *extra):
    return ["tune", root / "s", "--base", root / "base.yaml", "--optimizer", "ga", "--population", "8",
            "--generations", "12", "--seed", "4", "--workers", "2", "--no-progress", *extra]


@pytest.fixture(scope="module")
def reference_run(tiny_session, tmp_path_factory):
    """An uninterrupted run: its parameter file and report."""
    out = tmp_path_factory.mktemp("ref")
    cli(*_args(tiny_session, "--store", out / "store.sqlite", "--out", out / "p.yaml", "--report", out / "rep"))
    return out


def _count(store):
    try:
        with sqlite3.connect(store) as db:
            return db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0]
    except sqlite3.Error:
        return 0


def _start_and_wait(args, store, at_least):
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while _count(store) < at_least and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    return proc


def test_out_file_loads_in_the_daemons_loader_with_provenance(reference_run, tiny_session):
    params = load_params(reference_run / "p.yaml")
    prov = read_provenance(reference_run / "p.yaml")
    for key in ("metric", "fitness", "data", "seed", "optimizer", "version", "date", "frames_digest"):
        assert key in prov, key
    assert prov["metric"] == "mse" and prov["seed"] == 4 and prov["optimizer"] == "ga"
    assert prov["fitness"] <= prov["baseline_fitness"]
    assert params.sgbm.num_disparities == 48        # untuned keys keep the --base values
    assert prov["references"] == {"synthetic (exact ray-cast disparity)": 4}   # what it was measured against


def test_report_has_summary_table_plots_and_images(reference_run, tiny_session):
    rep = reference_run / "rep"
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["config"]["population"] == 8 and len(summary["runs"][0]["history"]) == 12
    assert summary["comparison"]["train"]["metrics"]["mse"]["tuned"] <= \
        summary["comparison"]["train"]["metrics"]["mse"]["base"]
    table = (rep / "table.md").read_text()
    assert "| train (4) | mse |" in table and "-42.86%" in table and "+28.52%" in table
    assert f"vs the base it started from: {tiny_session / 'base.yaml'}." in table    # not "manual": --base given
    assert "Reference disparity of the train frames: 4 x synthetic (exact ray-cast disparity)." in table
    assert summary["references"] == {"train": {"synthetic (exact ray-cast disparity)": 4}}
    for name in ("convergence.png", "pareto.png", "config.yaml"):
        assert (rep / name).stat().st_size > 0
    assert len(list((rep / "frames").glob("train_*.png"))) == 2


def test_resume_after_kill_ends_with_the_uninterrupted_result(reference_run, tiny_session, tmp_path):
    store, out = tmp_path / "store.sqlite", tmp_path / "p.yaml"
    args = _args(tiny_session, "--store", store, "--out", out)
    proc = _start_and_wait(args, store, at_least=8)
    os.killpg(proc.pid, signal.SIGKILL)            # the run and its workers, mid-run
    proc.wait(timeout=30)
    done = _count(store)
    assert done >= 8 and not out.exists()
    resumed = cli(*args, "--resume")
    assert "evaluated" in resumed.stdout
    assert load_params(out) == load_params(reference_run / "p.yaml")
    assert read_provenance(out)["fitness"] == read_provenance(reference_run / "p.yaml")["fitness"]
    with sqlite3.connect(store) as a, sqlite3.connect(reference_run / "store.sqlite") as b:
        q = "SELECT run, generation, idx, key, utility FROM trials ORDER BY run, generation, idx"
        assert a.execute(q).fetchall() == b.execute(q).fetchall()


def test_ctrl_c_keeps_finished_work_and_resume_finishes_it(reference_run, tiny_session, tmp_path):
    store, out = tmp_path / "store.sqlite", tmp_path / "p.yaml"
    args = _args(tiny_session, "--store", store, "--out", out)
    proc = _start_and_wait(args, store, at_least=8)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert "interrupted" in err and "--resume" in err and "Traceback" not in err
    kept = _count(store)
    assert kept >= 8 and not out.exists()
    cli(*args, "--resume")
    assert load_params(out) == load_params(reference_run / "p.yaml")


def test_existing_store_needs_resume_and_resume_needs_the_same_settings(reference_run, tiny_session):
    store = reference_run / "store.sqlite"
    again = cli(*_args(tiny_session, "--store", store), check=False)
    assert again.returncode == EXIT_CONFIG and "pass --resume" in again.stderr
    other = cli(*_args(tiny_session, "--store", store, "--seed", "5", "--resume"), check=False)
    assert other.returncode == EXIT_CONFIG and "--resume (seed) must match the stored run" in other.stderr
    assert other.stderr.strip().count("\n") == 0


def test_resume_of_a_finished_run_evaluates_nothing(reference_run, tiny_session, tmp_path):
    import shutil

    store = tmp_path / "store.sqlite"
    shutil.copy(reference_run / "store.sqlite", store)
    out = cli(*_args(tiny_session, "--store", store, "--resume", "--out", tmp_path / "p.yaml")).stdout
    assert "[0 evaluated" in out
    assert load_params(tmp_path / "p.yaml") == load_params(reference_run / "p.yaml")


def test_holdout_and_max_ms(tiny_session, tmp_path):
    proc = cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
               "--population", "5", "--generations", "2", "--workers", "1", "--holdout", "0.5", "--max-ms", "10000",
               "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml", "--no-progress")
    assert "held-out (2)" in proc.stdout
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["frames"]["holdout"] == ["s/000002", "s/000003"]
    assert summary["budget"]["chosen"]["ms"] <= 10000 and summary["budget"]["front"]
    too_fast = cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
                   "--population", "3", "--generations", "1", "--workers", "1", "--max-ms", "0.001",
                   "--store", tmp_path / "s2.sqlite", "--out", tmp_path / "q.yaml", "--no-progress", check=False)
    assert too_fast.returncode == 1 and "no evaluated candidate runs within 0.001 ms" in too_fast.stderr
    assert not (tmp_path / "q.yaml").exists()


@pytest.mark.parametrize("extra, match", [
    (["--holdout", "1.5"], "--holdout must be a fraction between 0 and 1"),
    (["--holdout", "nosuchsession"], "--holdout must name sessions"),
    (["--keys", "sgbm.p9"], "--keys must name parameter-file keys"),
    (["--population", "1"], "--population must be an integer of at least 2"),
    (["--max-ms", "0"], "--max-ms must be greater than 0"),
], ids=["holdout-fraction", "holdout-name", "keys", "population", "max-ms"])
def test_bad_arguments_are_one_line_config_errors(tiny_session, tmp_path, extra, match):
    proc = cli("tune", tiny_session / "s", "--store", tmp_path / "x.sqlite", "--no-progress", *extra, check=False)
    assert proc.returncode == EXIT_CONFIG and match in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
