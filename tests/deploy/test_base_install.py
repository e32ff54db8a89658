"""The drone's install is the base package (install.sh installs no extras): the daemon must run without them.

Installing the real base dependencies into a fresh venv takes minutes, so these tests run the CLI
with every module of the optional extras (pyproject's [project.optional-dependencies]) made
unimportable, which is what a base install looks like to Python.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from uav_depth.cli.main import COMMANDS
from uav_depth.core.errors import EXTRA_OF_MODULE

REPO = Path(__file__).resolve().parents[2]


def _dist(requirement: str) -> str:
    for sep in "[<>=!~; ":
        requirement = requirement.split(sep)[0]
    return requirement.strip().lower()


def _pyproject_extras() -> dict[str, set[str]]:
    """extra -> distributions it adds over the base install (dev left out: it is for us, not users)."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    base = {_dist(d) for d in project["dependencies"]}
    return {extra: {_dist(d) for d in deps} - base - {"uav-depth"}
            for extra, deps in project["optional-dependencies"].items() if extra != "dev"}


#: distribution name -> import name, where they differ
IMPORT_NAMES = {"scikit-image": "skimage"}


def test_every_extra_module_is_known_to_the_error_table():
    from_pyproject = {IMPORT_NAMES.get(dist, dist.replace("-", "_")): extra
                      for extra, dists in _pyproject_extras().items() for dist in dists}
    assert from_pyproject == EXTRA_OF_MODULE


BLOCK = """
import sys, importlib.abc
blocked = set(sys.argv[1].split(","))
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Block())
from uav_depth.cli.main import main
sys.exit(main(sys.argv[2:]))
"""


def _base_install(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK, ",".join(sorted(EXTRA_OF_MODULE)), *argv],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize("argv", [["--help"], *([c, "--help"] for c in sorted(COMMANDS)), ["params", "default"],
                                  ["sources"]],
                         ids=["help", *(f"{c}-help" for c in sorted(COMMANDS)), "params", "sources"])
def test_daemon_commands_run_without_the_extras(argv):
    proc = _base_install(*argv)
    assert proc.returncode == 0, (
        f"uav-depth {' '.join(argv)} fails on the base install (install.sh installs no extras, so "
        f"systemd's 'uav-depth run' would too):\n{proc.stderr[-1500:]}")


def test_tune_without_the_extra_names_it_in_one_line(tmp_path):
    proc = _base_install("tune", str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "uav-depth[tuning]" in lines[0] and lines[0].startswith("uav-depth tune: error:")


def test_the_daemon_flies_a_replay_without_the_extras(tmp_path):
    """Not only --help: `uav-depth run` processes frames and ends cleanly on the base install."""
    import yaml

    from mavlink_peer import free_port
    from uav_depth.sim.scene import SceneConfig, write_session

    write_session(tmp_path / "s", 3, 1, SceneConfig(width=320, height=240, focal_px=200.0))
    config = tmp_path / "run.yaml"
    config.write_text(yaml.safe_dump({
        # lossless: every frame is processed however loaded the machine is (paced replay drops frames)
        "source": {"kind": "replay", "path": str(tmp_path / "s"), "rate_hz": 10, "lossless": True},
        "mavlink": {"url": f"udpout:127.0.0.1:{free_port()}"},
        "logging": {"dir": str(tmp_path / "logs"), "every_n": 1}}))
    proc = _base_install("run", "--config", str(config), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert "Traceback" not in proc.stderr
    assert len(list((tmp_path / "logs").glob("*/frames/*_left.png"))) == 3    # it measured and logged every frame
