"""``--set``: one rule for run, sitl, evaluate and tune, and a bad item is one line and exit 78 from every one.

Through the real command (a subprocess per case), so that a traceback or another exit code shows.
"""

import subprocess
import sys

import pytest

from uav_depth.cli.exit_codes import EXIT_CONFIG
from uav_depth.cli.main import main
from uav_depth.cli.overrides import apply_sets, parse_sets
from uav_depth.core.errors import ConfigError
from uav_depth.core.params import DEFAULT_PARAMS


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("sets")
    assert main(["synth", str(root / "s"), "--frames", "2", "--seed", "1", "--width", "160", "--height", "120",
                 "--focal-px", "100"]) == 0
    (root / "run.yaml").write_text("source: {kind: synthetic}\n")
    return root


def command(name: str, root):
    """The arguments of ``name`` that reach its ``--set`` handling, given a good session and run config."""
    return {"run": ["run", "--config", root / "run.yaml", "--check"],
            "sitl": ["sitl", "--config", root / "run.yaml", "--check"],
            "evaluate": ["evaluate", root / "s"],
            "tune": ["tune", root / "s", "--store", root / "t.sqlite", "--no-progress"]}[name]


BAD = {   # command -> (item, what the line must name)
    "run": [("nosuch.key=1", "nosuch is not a known section"), ("mavlink.nosuch=1", "mavlink.nosuch is not a known"),
            ("=1", "--set must look like KEY=VALUE"), ("a..b=1", "--set must look like KEY=VALUE")],
    "evaluate": [("nosuch.key=1", "nosuch is not a known section"), ("sgbm.nosuch=1", "sgbm.nosuch is not a known"),
                 ("sgbm.p1", "--set must look like SECTION.KEY=VALUE"),
                 ("sgbm.p1.x=1", "--set must look like SECTION.KEY=VALUE"),
                 ("sgbm.block_size=4", "sgbm.block_size must be odd")],
}
BAD["sitl"], BAD["tune"] = BAD["run"][::2], BAD["evaluate"][::2]     # the same rule: a few items are enough
CASES = [(name, item, match) for name, items in BAD.items() for item, match in items]


@pytest.mark.parametrize("name, item, match", CASES, ids=[f"{n}-{i}" for n, i, _ in CASES])
def test_a_bad_set_is_one_line_and_exit_78(inputs, name, item, match):
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, command(name, inputs)),
                           "--set", item], capture_output=True, text=True, timeout=300)
    assert proc.returncode == EXIT_CONFIG, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"uav-depth {name}") and match in lines[0], proc.stderr[-2000:]


def test_values_are_read_alike_for_the_config_and_the_parameters():
    items = ["a.b=64", "a.c=[0.25, 0.25, 0.75, 0.75]", "a.d=true", "a.e=", "a.f=sgbm_3way", "a.g=: not yaml"]
    expected = {"a.b": 64, "a.c": [0.25, 0.25, 0.75, 0.75], "a.d": True, "a.e": None, "a.f": "sgbm_3way",
                "a.g": ": not yaml"}
    assert parse_sets(items) == parse_sets(items, parts=2) == expected
    assert parse_sets(["a.b=1", "a.b=2"]) == {"a.b": 2}           # the last of a key wins
    assert parse_sets(["params_file=/x.yaml"]) == {"params_file": "/x.yaml"}
    with pytest.raises(ConfigError, match=r"^--set must look like SECTION\.KEY=VALUE"):
        parse_sets(["params_file=/x.yaml"], parts=2)


def test_parameter_sets_are_checked_by_the_schema():
    changed = apply_sets(DEFAULT_PARAMS, ["sgbm.num_disparities=64", "compute.roi=[0.2, 0.2, 0.8, 0.8]"])
    assert changed.sgbm.num_disparities == 64 and changed.compute.roi == (0.2, 0.2, 0.8, 0.8)
    assert apply_sets(DEFAULT_PARAMS, []) is DEFAULT_PARAMS
    with pytest.raises(ConfigError, match=r"^--set: sgbm\.p2 must be greater than sgbm\.p1"):
        apply_sets(DEFAULT_PARAMS, ["sgbm.p1=5000"])
    with pytest.raises(ConfigError, match=r"^--set: nosuch is not a known section"):
        apply_sets(DEFAULT_PARAMS, ["nosuch.key=1"])
