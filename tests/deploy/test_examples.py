"""The example configs install.sh offers are valid run configs, and match the deployed layout."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uav_depth.cli.sources import SOURCES
from uav_depth.daemon.config import load_run_config

EXAMPLES = Path(__file__).resolve().parents[2] / "deploy" / "examples"
KINDS = {"zed-mini": "uvc", "oak-d": "oak", "sitl": "synthetic"}


@pytest.mark.parametrize("name", sorted(KINDS))
def test_example_validates_and_uses_the_state_directory(name):
    config = load_run_config(EXAMPLES / f"{name}.yaml", environ={}, sources=SOURCES)
    assert config.source_kind == KINDS[name]
    if name == "sitl":
        # The laptop example runs as a normal user: its flight file is the repo's, matched to its 640x360.
        assert config.params_file.resolve() == (EXAMPLES.parent / "params-flight-640x360.yaml").resolve()
        assert config.params_file.exists() and config.logging.dir is None
    else:
        # ProtectSystem=strict leaves only /var/lib/uav-depth writable: the tuned parameters and logs live there.
        assert str(config.params_file) == "/var/lib/uav-depth/params.yaml"
        assert config.logging.dir is None or str(config.logging.dir).startswith("/var/lib/uav-depth/")
    # ArduPilot drops messages carrying its own ids; the orientation must match RNGFND1_ORIENT=0.
    assert (config.mavlink.system_id, config.mavlink.component_id) != (1, 1)
    assert config.mavlink.orientation == "forward"


def test_examples_are_all_offered():
    assert {p.stem for p in EXAMPLES.glob("*.yaml")} == set(KINDS)
    script = (EXAMPLES.parent / "install.sh").read_text()
    assert "zed-mini|oak-d|sitl)" in script


def test_sitl_example_checks_under_uav_depth_sitl():
    proc = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "sitl", "--config",
                           str(EXAMPLES / "sitl.yaml"), "--check"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "source synthetic" in proc.stdout and "tree 3 m in front of the start pose" in proc.stdout
