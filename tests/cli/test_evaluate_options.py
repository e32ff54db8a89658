"""evaluate --set and --roi, and the branch-distance error where the truth is known."""

import json
import math

import pytest

from uav_depth.cli.exit_codes import EXIT_CONFIG
from uav_depth.cli.main import main
from uav_depth.core.params import DEFAULT_PARAMS


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("ev") / "s"
    assert main(["synth", str(out), "--frames", "2", "--seed", "4", "--width", "320", "--height", "240",
                 "--focal-px", "200"]) == 0
    return out


def evaluate(capsys, *args):
    code = main(["evaluate", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_set_changes_the_parameters_scored(session, capsys):
    _, base, _ = evaluate(capsys, str(session), "--json")
    _, changed, _ = evaluate(capsys, str(session), "--json", "--set", "sgbm.num_disparities=64",
                             "--set", "sgbm.block_size=7")
    assert json.loads(base)["params_hash"] == DEFAULT_PARAMS.hash()
    assert json.loads(changed)["params_hash"] == DEFAULT_PARAMS.replace(
        **{"sgbm.num_disparities": 64, "sgbm.block_size": 7}).hash()


def test_roi_scores_two_files_in_the_same_box(session, capsys, tmp_path):
    from uav_depth.core.params import save_params

    narrow = tmp_path / "narrow.yaml"
    save_params(DEFAULT_PARAMS.replace(**{"compute.roi": (0.3, 0.3, 0.7, 0.7)}), narrow)
    box = ["--roi", "0.3,0.3,0.7,0.7"]
    a = json.loads(evaluate(capsys, str(session), "--json", *box)[1])
    b = json.loads(evaluate(capsys, str(session), "--json", "--params", str(narrow), *box)[1])
    assert a["scored"] == b["scored"] == "--roi [0.3, 0.3, 0.7, 0.7]"
    whole = json.loads(evaluate(capsys, str(session), "--json")[1])
    assert whole["scored"] == "whole frame" and whole["mean"]["bad1"] != a["mean"]["bad1"]


def test_branch_distance_error_where_truth_exists(session, capsys):
    code, out, _ = evaluate(capsys, str(session))
    assert code == 0 and "truth m" in out and "branch distance: median error" in out
    doc = json.loads(evaluate(capsys, str(session), "--json")[1])
    for f in doc["frames"]:
        assert f["truth_m"] > 0
        if f["branch_m"] is not None:
            assert f["branch_err_pct"] == pytest.approx(abs(f["branch_m"] - f["truth_m"]) / f["truth_m"] * 100)
    assert math.isfinite(doc["mean"]["branch_err_median_pct"])


@pytest.mark.parametrize("args, key", [(["--set", "nosuch=1"], "--set"), (["--set", "sgbm.nosuch=1"], "sgbm.nosuch"),
                                       (["--roi", "0.5,0,0.2,1"], "--roi"), (["--roi", "a,b"], "--roi")],
                         ids=["set-no-section", "set-unknown-key", "roi-backwards", "roi-not-numbers"])
def test_bad_options_are_one_line_naming_them(session, capsys, args, key):
    code, _, err = evaluate(capsys, str(session), *args)
    assert code == EXIT_CONFIG and err.count("\n") == 1 and key in err
