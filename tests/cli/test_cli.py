"""The CLI end to end, as a user runs it (real subprocesses)."""

import json
import subprocess
import sys

import pytest

from uav_depth.cli.exit_codes import EXIT_CONFIG
from uav_depth.cli.main import COMMANDS


def cli(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *args], capture_output=True, text=True,
                          timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(proc.stderr)
    return proc


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_subcommand_has_help(command):
    out = cli(command, "--help").stdout
    assert "usage: uav-depth " + command in out


def test_synth_then_evaluate_json(tmp_path):
    cli("synth", str(tmp_path / "s"), "--frames", "2", "--seed", "3", "--width", "320", "--height", "240",
        "--focal-px", "200")
    doc = json.loads(cli("evaluate", str(tmp_path / "s"), "--json").stdout)
    assert [f["id"] for f in doc["frames"]] == ["s/000000", "s/000001"] and doc["convention"] == "bench"
    for key in ("mae", "rmse", "bad1", "bad2", "bad4", "psnr", "density", "branch_err_pct", "ms"):
        assert isinstance(doc["mean"][key], float)
    assert 0.3 < doc["mean"]["density"] <= 1 and doc["mean"]["bad1"] >= doc["mean"]["bad2"] >= doc["mean"]["bad4"]
    paper = json.loads(cli("evaluate", str(tmp_path / "s"), "--json", "--convention", "paper").stdout)
    for key in ("mse", "psnr", "ssim", "bad1", "bad2", "valid", "ms"):
        assert isinstance(paper["mean"][key], float)
    assert 0.3 < paper["mean"]["valid"] <= 1 and 0 < paper["mean"]["ssim"] <= 1 and paper["mean"]["mse"] > 0
    assert paper["convention"] == "paper"


def test_disparity_command_writes_outputs(tmp_path):
    cli("synth", str(tmp_path / "s"), "--frames", "1", "--width", "320", "--height", "240", "--focal-px", "200")
    frames = tmp_path / "s" / "frames"
    for suffix in (".npy", ".pfm", ".png"):
        cli("disparity", str(frames / "000000_left.png"), str(frames / "000000_right.png"),
            "--out", str(tmp_path / f"d{suffix}"))
        assert (tmp_path / f"d{suffix}").stat().st_size > 0


@pytest.mark.parametrize("width, height", [(8, 8), (100, 60), (130, 60)], ids=["8x8", "narrower", "no-margin"])
def test_a_pair_the_search_cannot_match_is_refused_with_the_rule(tmp_path, width, height):
    """The default search is 128 px plus half a 5-px block: a pair not wider than 130 px has no column to match.
    It says so (one line, the key, the width) and exits 78, instead of writing an all-invalid map with exit 0."""
    import cv2
    import numpy as np

    img = tmp_path / "pair.png"
    cv2.imwrite(str(img), (np.random.default_rng(0).random((height, width)) * 255).astype(np.uint8))
    proc = cli("disparity", str(img), str(img), "--out", str(tmp_path / "d.npy"), check=False)
    assert proc.returncode == EXIT_CONFIG, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("uav-depth disparity: error: ")
    assert "sgbm.num_disparities must leave columns to match" in lines[0] and f"width {width} px" in lines[0]
    assert not (tmp_path / "d.npy").exists() and proc.stdout == ""
    wide = tmp_path / "wide.png"            # one column more, and it computes
    cv2.imwrite(str(wide), (np.random.default_rng(0).random((60, 131)) * 255).astype(np.uint8))
    assert "valid" in cli("disparity", str(wide), str(wide), "--out", str(tmp_path / "w.npy")).stdout


def test_bad_params_file_is_one_line_and_config_exit(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("sgbm:\n  num_disparities: 40\n")
    proc = cli("params", "check", str(bad), check=False)
    assert proc.returncode == EXIT_CONFIG
    assert proc.stderr.strip().count("\n") == 0
    assert "sgbm.num_disparities must be a positive multiple of 16, but got 40" in proc.stderr


@pytest.mark.parametrize("data,message", [
    (b"", r"must set at least one section \(sgbm, wls, compute\); an empty file is not taken as the defaults"),
    (b"sgbm:\n  p1: 600 # caf\xe9\n", r"parameter file is not UTF-8 text \(byte 0xe9"),
    (b"sgbm:\n  p2: 2400\n  p2: 2500\n", r"sgbm\.p2 is given twice \(line 2 and line 3\)"),
    (b"sgbm:\n  p1: 600\n  p2: 40000\n", r"sgbm\.p2 must be at most 32767"),
    (b"\x00\x01", r"parameter file is a binary file"),
], ids=["empty", "not-utf8", "duplicate-key", "p2-over-16-bit-costs", "binary"])
def test_params_check_applies_the_daemons_rules(tmp_path, data, message):
    import re

    bad = tmp_path / "p.yaml"
    bad.write_bytes(data)
    proc = cli("params", "check", str(bad), check=False)
    assert proc.returncode == EXIT_CONFIG, proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    assert re.search(message, proc.stderr), proc.stderr


def test_params_check_against_a_camera_runs_the_test_render(tmp_path):
    calib = tmp_path / "calib.yaml"
    calib.write_text("focal_px: 200.0\nbaseline_m: 0.063\nwidth: 320\nheight: 240\n")
    good = tmp_path / "good.yaml"
    good.write_text("sgbm:\n  num_disparities: 64\n")
    assert "measures a test render at 320x240" in cli("params", "check", str(good), "--calibration",
                                                      str(calib)).stdout
    hides = tmp_path / "hides.yaml"         # the search range leaves the central ROI unmatched
    hides.write_text("sgbm:\n  num_disparities: 224\n  block_size: 31\n")
    assert cli("params", "check", str(hides)).returncode == 0        # the schema alone cannot tell
    proc = cli("params", "check", str(hides), "--calibration", str(calib), check=False)
    assert proc.returncode == EXIT_CONFIG
    assert "(parameters) must measure a test render" in proc.stderr and "Traceback" not in proc.stderr


def test_set_of_an_unknown_key_blames_the_command_line(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("source: {kind: synthetic}\n")
    proc = cli("run", "--config", str(cfg), "--set", "nosuch.key=1", "--check", check=False)
    assert proc.returncode == EXIT_CONFIG
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "uav-depth run --check: error: command line: nosuch is not a known section (known: source, calibration, ")
    assert lines[0].endswith("), but got {'key': 1}") and str(cfg) not in lines[0]
    proc = cli("run", "--config", str(cfg), "--set", "mavlink.nosuch=1", "--check", check=False)
    assert proc.returncode == EXIT_CONFIG and "error: command line: mavlink.nosuch is not a known key" in proc.stderr


def test_missing_logdir_is_clear(tmp_path):
    proc = cli("evaluate", str(tmp_path / "nowhere"), check=False)
    assert proc.returncode == 1 and "log directory not found" in proc.stderr and "Traceback" not in proc.stderr


def test_evaluate_scores_inside_the_params_region_and_names_its_references(tmp_path):
    cli("synth", str(tmp_path / "s"), "--frames", "2", "--seed", "3", "--width", "320", "--height", "240",
        "--focal-px", "200")
    params = tmp_path / "p.yaml"
    params.write_text("sgbm: {num_disparities: 48}\ncompute: {roi: [0.25, 0.25, 0.75, 0.75]}\n")
    region = json.loads(cli("evaluate", str(tmp_path / "s"), "--json", "--params", str(params)).stdout)
    assert region["scored"] == "compute.roi [0.25, 0.25, 0.75, 0.75]"
    # outside the region the pipeline answers nothing by design: that must not count as missing pixels
    assert region["mean"]["density"] > 0.5
    paper = json.loads(cli("evaluate", str(tmp_path / "s"), "--json", "--params", str(params),
                           "--convention", "paper").stdout)
    assert paper["mean"]["valid"] > 0.9
    assert region["references"]["by_kind"] == {"synthetic": 2}
    for json_file in (tmp_path / "s" / "frames").glob("*_ref.json"):
        json_file.unlink()
    text = cli("evaluate", str(tmp_path / "s")).stdout
    # frames without provenance are one line, not one per frame
    assert "scored: whole frame, bench convention; measured against: 2 x unknown (no readable provenance recorded)\n" in text
