"""The CLI end to end, as a user runs it (real subprocesses)."""

import json
import subprocess
import sys

import pytest

from uav_depth.cli.main import COMMANDS, EXIT_CONFIG


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
    for key in ("mae", "rmse", "bad1", "bad2", "bad4", "psnr", "density", "branch", "ms"):
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


def test_bad_params_file_is_one_line_and_config_exit(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("sgbm:\n  num_disparities: 40\n")
    proc = cli("params", "check", str(bad), check=False)
    assert proc.returncode == EXIT_CONFIG
    assert proc.stderr.strip().count("\n") == 0
    assert "sgbm.num_disparities must be a positive multiple of 16, but got 40" in proc.stderr


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
