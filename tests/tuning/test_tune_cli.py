"""uav-depth tune as a user runs it: real subprocesses, real files, a real kill and a real Ctrl-C."""

import json
import os
import signal
import subprocess
import sys
import time

import optuna
import pytest
import yaml

from uav_depth.cli.exit_codes import EXIT_CONFIG
from uav_depth.core.params import load_params, read_provenance
from uav_depth.tuning.store import STUDY_NAME, RunStore, storage_url


def cli(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(proc.stderr)
    return proc


def _args(root, *extra, generations=12):
    """The paper's metric on all four frames (``--holdout none``: no validation and no test frame, the gate
    compares on the training frames).

    ``--force`` and ``--safety-sweep none``: these runs test the store, resume and report, not the gate (its own
    tests are below and in test_farther.py), and the sweep's 84 renders would add 13 s to each."""
    return ["tune", root / "s", "--base", root / "base.yaml", "--optimizer", "ga", "--metric", "mse",
            "--holdout", "none", "--population", "8", "--generations", str(generations), "--seed", "4",
            "--workers", "2", "--no-progress", "--force", "--safety-sweep", "none", *extra]


@pytest.fixture(scope="module")
def reference_run(tiny_session, tmp_path_factory):
    """An uninterrupted run: its parameter file and report."""
    out = tmp_path_factory.mktemp("ref")
    cli(*_args(tiny_session, "--store", out / "store.sqlite", "--out", out / "p.yaml", "--report", out / "rep"))
    return out


def _count(store):
    """Trials in the store, read through Optuna's own API (0 before the run created it)."""
    if not store.exists():
        return 0
    try:
        return len(optuna.load_study(study_name=STUDY_NAME, storage=storage_url(store)).trials)
    except Exception:          # the run is still creating the schema or the study
        return 0


def _trials(store):
    with RunStore(store) as s:
        return s.trials()


def _start_and_wait(args, store, at_least):
    proc = subprocess.Popen([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while _count(store) < at_least and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if proc.poll() is not None:
        out, err = proc.communicate()
        raise AssertionError(f"the run ended (exit {proc.returncode}) before it could be interrupted: {err[-3000:]}")
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
    assert "the paper's convention" in table and summary["convention"] == "paper"
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
    assert _trials(store) == _trials(reference_run / "store.sqlite")


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
    assert ": 0 evaluated" in out
    assert load_params(tmp_path / "p.yaml") == load_params(reference_run / "p.yaml")


def test_holdout_and_max_ms(tiny_session, tmp_path):
    proc = cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
               "--population", "5", "--generations", "2", "--workers", "1", "--holdout", "0.5", "--max-ms", "10000",
               "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml", "--no-progress", "--force")
    assert "validation (2, chosen on it)" in proc.stdout
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    # --test auto: the last 20 % of the single session; --holdout 0.5: half of the frames left
    assert summary["frames"] == {"train": ["s/000000"], "validation": ["s/000001", "s/000002"],
                                 "test": ["s/000003"]}
    assert summary["budget"]["chosen"]["ms"] <= 10000 and summary["budget"]["front"]
    too_fast = cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
                   "--population", "3", "--generations", "1", "--workers", "1", "--max-ms", "0.001",
                   "--store", tmp_path / "s2.sqlite", "--out", tmp_path / "q.yaml", "--no-progress", check=False)
    assert too_fast.returncode == 1 and "no evaluated candidate runs within 0.001 ms" in too_fast.stderr
    assert not (tmp_path / "q.yaml").exists()


@pytest.mark.parametrize("extra, match", [
    (["--holdout", "1.5"], "--holdout must be a fraction between 0 and 1"),
    (["--test", "0"], "--test must be a fraction between 0 and 1"),
    (["--holdout", "nosuchsession"], "--holdout must name sessions"),
    (["--keys", "sgbm.p9"], "--keys must name parameter-file keys"),
    (["--population", "1"], "--population must be an integer of at least 2"),
    (["--max-ms", "0"], "--max-ms must be greater than 0"),
    (["--keys", "sgbm.p1,wls.lambda"], "--keys must change what flies"),
    (["--timeout", "0"], "--timeout must be greater than 0 seconds"),
    (["--set", "num_disparities"], "--set must look like SECTION.KEY=VALUE"),
    (["--set", "sgbm.nosuch=1"], "--set: sgbm.nosuch is not a known key"),
], ids=["holdout-fraction", "test-fraction", "holdout-name", "keys", "population", "max-ms", "wls-not-flown",
        "timeout", "set-malformed", "set-unknown-key"])
def test_bad_arguments_are_one_line_config_errors(tiny_session, tmp_path, extra, match):
    proc = cli("tune", tiny_session / "s", "--store", tmp_path / "x.sqlite", "--no-progress", *extra, check=False)
    assert proc.returncode == EXIT_CONFIG and match in proc.stderr
    assert proc.stderr.strip().count("\n") == 0


def test_default_tune_flies_chooses_on_validation_frames_and_reports_benchmark_metrics(tiny_session, tmp_path):
    proc = cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--population", "6",
               "--generations", "3", "--workers", "1", "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml",
               "--no-progress", "--force", "--safety-sweep", "quick")   # the standard sweep's 330 frames: for time
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["config"]["metric"] == "flown" and summary["config"]["optimizer"] == "tpe"
    assert summary["convention"] == "bench"
    # auto, a single session of 4: the last frame is the test, of the 3 left the last one (30 %) the validation
    assert summary["frames"] == {"train": ["s/000000", "s/000001"], "validation": ["s/000002"],
                                 "test": ["s/000003"]}
    assert summary["selection"]["on"] == "validation" and len(summary["selection"]["candidates"]) >= 2
    assert summary["gate"]["on"] == "test" and any("correlated" in n for n in summary["notes"])
    dims = yaml.safe_load((tmp_path / "rep" / "config.yaml").read_text())["space"]["dims"]
    assert dims and not [d["key"] for d in dims if d["key"].startswith("wls.")]   # WLS never reaches what flies
    held = summary["comparison"]["test"]["metrics"]
    for key in ("mae", "bad2", "bad4", "density", "psnr"):
        assert key in held, key
    table = (tmp_path / "rep" / "table.md").read_text()
    assert "benchmark convention" in table and "-42.86%" not in table and "Gate, on the 1 test frame(s)" in table
    assert "wrote " in proc.stdout and "optuna-dashboard sqlite:///" in proc.stdout


def test_set_changes_the_base_the_search_starts_from_and_keeps(tiny_session, tmp_path):
    """tune --set: the search range per data set without writing a parameter file by hand."""
    out = tmp_path / "p.yaml"
    cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--set", "sgbm.num_disparities=32",
        "--optimizer", "random", "--keys", "sgbm.uniqueness_ratio", "--population", "2", "--generations", "1",
        "--workers", "1", "--no-progress", "--force", "--store", tmp_path / "s.sqlite", "--out", out,
        "--report", tmp_path / "rep", "--safety-sweep", "quick")
    assert load_params(tiny_session / "base.yaml").sgbm.num_disparities == 48
    assert load_params(out).sgbm.num_disparities == 32          # an untuned key comes from the changed base
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["base"].endswith("base.yaml --set sgbm.num_disparities=32")


def test_tune_refuses_to_write_a_worse_file_and_keeps_the_candidate_beside_it(tiny_session, tmp_path):
    out = tmp_path / "params.yaml"
    good = tiny_session / "base.yaml"
    out.write_bytes(good.read_bytes())
    before = out.read_bytes()
    # one random candidate against a base that is already good: seed 5 draws one that loses on the validation
    # frames
    args = ["tune", tiny_session / "s", "--base", good, "--optimizer", "random", "--population", "2",
            "--generations", "1", "--seed", "5", "--workers", "1", "--keys", "sgbm.uniqueness_ratio",
            "--no-progress", "--out", out, "--safety-sweep", "quick"]   # 84 sweep frames, not 330: for time
    proc = cli(*args, "--store", tmp_path / "a.sqlite", check=False)
    assert proc.returncode == 1, proc.stdout
    assert "not written: no candidate beats the base on the validation frames the choice was made on" in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
    assert out.read_bytes() == before
    rejected = tmp_path / "params.rejected.yaml"
    prov = read_provenance(rejected)
    assert prov["validation_fitness"] >= prov["validation_baseline_fitness"] and prov["chosen_on"] == "validation"
    assert load_params(rejected) != load_params(good)      # the search's candidate, not the base again
    forced = cli(*args, "--store", tmp_path / "b.sqlite", "--force")
    assert "--force" in forced.stdout and read_provenance(out)["forced"] is True


def test_tune_refuses_a_better_map_that_ranges_worse(tiny_session, tmp_path):
    """The paper's MSE improves on these frames while the daemon's branch distance gets worse: not written."""
    out = tmp_path / "p.yaml"
    # seed 2: its GA halves the MSE while the daemon's safety-weighted branch error goes from 78.8 % to 100 %
    args = [a for a in _args(tiny_session, "--store", tmp_path / "s.sqlite", "--out", out) if a != "--force"]
    args[args.index("--seed") + 1] = "2"
    proc = cli(*args, check=False)
    assert proc.returncode == 1 and not out.exists(), proc.stdout
    assert "safety-weighted branch-distance error on the 4 train frame(s)" in proc.stderr
    prov = read_provenance(tmp_path / "p.rejected.yaml")
    assert prov["fitness"] < prov["baseline_fitness"]       # it did beat the base on the fitness it was given


def test_the_safety_sweep_runs_at_the_logs_rig_and_is_reported(tiny_session, tmp_path):
    """A candidate that differs from its base is ranged on the quick sweep's 84 frames (``--safety-sweep quick``;
    the default is the 330-frame standard sweep, tests/sim/test_sweep.py), rendered at this log's 256x192 rig; the
    counts are printed and in summary.json. --safety-sweep none skips it. (``--holdout none``: chosen on the
    training frames, where this seed's GA finds candidates that beat the base, so one is about to win.)"""
    args = ["tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "ga",
            "--population", "6", "--generations", "2", "--seed", "5", "--workers", "1", "--no-progress", "--force",
            "--holdout", "none"]
    proc = cli(*args, "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml", "--safety-sweep", "quick")
    sweep = json.loads((tmp_path / "rep" / "summary.json").read_text())["gate"]["safety_sweep"]
    assert sweep["frames"] == 84
    assert (f"safety sweep (84 synthetic frames at the log's rig): read farther than the truth by more than 2 %: "
            f"base {sweep['base']}, tuned {sweep['tuned']}") in proc.stdout
    # the tiny base reads some of them farther (its 48 disparities at f = 160 px: minimum range 0.21 m)
    assert sweep["base"] > 0
    skipped = cli(*args, "--report", tmp_path / "rep2", "--out", tmp_path / "q.yaml", "--safety-sweep", "none")
    assert "safety sweep" not in skipped.stdout
    assert json.loads((tmp_path / "rep2" / "summary.json").read_text())["gate"]["safety_sweep"] is None


def test_a_tpe_tune_is_led_by_the_search_guide_and_says_what_it_found(tiny_session, tmp_path):
    """With a safety sweep, TPE reads each candidate that beats the base on the 70 frames of the search guide at
    the log's rig too; what it found is printed and in summary.json, per fold. Without a sweep there is no
    guide."""
    args = ["tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--population", "6",
            "--generations", "2", "--seed", "2", "--workers", "1", "--no-progress", "--force", "--holdout", "none"]
    proc = cli(*args, "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml", "--safety-sweep", "quick")
    guide = json.loads((tmp_path / "rep" / "summary.json").read_text())["guide"]
    assert len(guide) == 1 and guide[0]["frames"] == 70 and guide[0]["candidates"] >= 6
    assert 0 <= guide[0]["better_and_feasible"] <= guide[0]["better"] <= guide[0]["candidates"]
    assert (f"search guide (70 branches at the log's rig, seeds the safety sweep does not use; the base reads "
            f"{guide[0]['base_farther']} of them farther than the truth by more than 2 %): "
            f"{guide[0]['better_and_feasible']} of the {guide[0]['better']} candidates that beat the base on their "
            "training frames passed the safety sweep's rules on it") in proc.stdout
    none = cli(*args, "--report", tmp_path / "rep2", "--out", tmp_path / "q.yaml", "--safety-sweep", "none")
    assert "search guide" not in none.stdout + none.stderr
    assert json.loads((tmp_path / "rep2" / "summary.json").read_text())["guide"] is None


def test_the_default_safety_sweep_is_the_standard_one():
    """A plain ``tune`` checks its candidates on the 330-frame sweep; the 84-frame quick one let through a
    candidate that reads 104 leafy frames of the 1 cm near sweep farther than 2 %, the flight file 60."""
    from uav_depth.cli.main import build_parser

    assert build_parser().parse_args(["tune", "logs"]).safety_sweep == "standard"


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a file to another owner needs root")
def test_tune_keeps_owner_and_mode_of_an_existing_out_file(tiny_session, tmp_path):
    import pwd

    nobody = pwd.getpwnam("nobody")
    out = tmp_path / "params.yaml"
    out.write_bytes((tiny_session / "base.yaml").read_bytes())
    os.chown(out, nobody.pw_uid, nobody.pw_gid)
    os.chmod(out, 0o640)
    cli("tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
        "--population", "2", "--generations", "1", "--workers", "1", "--no-progress", "--force",
        "--store", tmp_path / "s.sqlite", "--out", out, "--safety-sweep", "quick")
    st = out.stat()
    assert (st.st_uid, st.st_gid, st.st_mode & 0o7777) == (nobody.pw_uid, nobody.pw_gid, 0o640)
    assert read_provenance(out)["tool"] == "uav-depth tune"


def test_the_store_is_an_optuna_study_the_dashboard_can_open(reference_run):
    url = storage_url(reference_run / "store.sqlite")
    summaries = optuna.get_all_study_summaries(storage=url)
    assert [s.study_name for s in summaries] == [STUDY_NAME] and summaries[0].n_trials > 10
    study = optuna.load_study(study_name=STUDY_NAME, storage=url)
    assert study.direction == optuna.study.StudyDirection.MINIMIZE            # mse
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    prov = read_provenance(reference_run / "p.yaml")
    assert min(t.value for t in done) == prov["fitness"]                      # bit for bit
    assert "sgbm.p1" in done[0].params and done[0].user_attrs["params"]["sgbm"]["p1"] == done[0].params["sgbm.p1"]
    assert study.user_attrs["config"]["seed"] == 4


def test_resume_with_more_generations_extends_the_study_to_the_longer_runs_result(reference_run, tiny_session,
                                                                                 tmp_path):
    import shutil

    shorter = tmp_path / "short.sqlite"
    cli(*_args(tiny_session, "--store", shorter, generations=6))
    n_short = _count(shorter)
    shutil.copy(shorter, tmp_path / "copy.sqlite")
    out = cli(*_args(tiny_session, "--store", shorter, "--resume", "--out", tmp_path / "p.yaml")).stdout
    assert ": 0 evaluated" not in out and _count(shorter) > n_short
    assert _trials(shorter) == _trials(reference_run / "store.sqlite")        # 6 + 6 = the 12-generation run
    assert load_params(tmp_path / "p.yaml") == load_params(reference_run / "p.yaml")


def test_timeout_stops_between_generations_and_resume_finishes_the_same(reference_run, tiny_session, tmp_path):
    store = tmp_path / "t.sqlite"
    first = cli(*_args(tiny_session, "--store", store, "--timeout", "0.5"))
    assert "stopped by --timeout" in first.stdout
    assert len(_trials(store)) < len(_trials(reference_run / "store.sqlite"))
    cli(*_args(tiny_session, "--store", store, "--resume", "--out", tmp_path / "p.yaml"))
    assert _trials(store) == _trials(reference_run / "store.sqlite")
    assert load_params(tmp_path / "p.yaml") == load_params(reference_run / "p.yaml")


def test_candidates_are_ranged_with_the_ranging_settings_of_the_config_that_will_fly(tiny_session, tmp_path):
    """``--config``: the run config the daemon will fly; its ranging: section is what every candidate is ranged
    with (here a stricter confidence), and the report says where the settings came from. A config run would
    refuse is refused the same way (exit 78, one line)."""
    config = tmp_path / "run.yaml"
    config.write_text("source:\n  kind: synthetic\nranging:\n  min_confidence: 0.9\n  min_quality: 50\n")
    args = ["tune", tiny_session / "s", "--base", tiny_session / "base.yaml", "--optimizer", "random",
            "--population", "2", "--generations", "1", "--workers", "1", "--no-progress", "--force",
            "--safety-sweep", "none"]
    cli(*args, "--config", config, "--report", tmp_path / "rep", "--out", tmp_path / "p.yaml")
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["ranging"]["from"] == f"the ranging settings of {config}"
    assert summary["ranging"]["min_confidence"] == 0.9 and summary["ranging"]["min_quality"] == 50
    assert read_provenance(tmp_path / "p.yaml")["ranging"]["min_confidence"] == 0.9
    config.write_text("source:\n  kind: synthetic\nranging:\n  min_confidence: 2\n")
    bad = cli(*args, "--config", config, "--store", tmp_path / "b.sqlite", check=False)
    assert bad.returncode == EXIT_CONFIG and "ranging.min_confidence" in bad.stderr
    assert bad.stderr.strip().count("\n") == 0
