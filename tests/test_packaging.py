"""The installed layout: uav_depth.daemon and uav_depth.tuning under a namespace, no top-level daemon."""

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_layout(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(ROOT)], check=True, capture_output=True, timeout=300)
    wheel = next(tmp_path.glob("uav_depth-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.startswith("uav_depth-")}
    assert tops == {"uav_depth"}, f"unexpected top-level entries {tops}"
    assert "uav_depth/__init__.py" not in names, "uav_depth must stay a namespace"
    # every package directory in the source tree is shipped
    for src, dst in (("core", "uav_depth/core"), ("daemon", "uav_depth/daemon"), ("tuning", "uav_depth/tuning")):
        for init in (ROOT / src).rglob("__init__.py"):
            rel = init.relative_to(ROOT / src).as_posix()
            assert f"{dst}/{rel}" in names, f"{src}/{rel} missing from the wheel: list it in pyproject packages"
        for py in (ROOT / src).rglob("*.py"):
            rel = py.relative_to(ROOT / src).as_posix()
            assert f"{dst}/{rel}" in names, f"{src}/{rel} missing from the wheel"
    # the recommended flight settings ship with the package, the very files deploy/ installs
    for name in ("params-flight.yaml", "params-flight-640x360.yaml"):
        shipped = zipfile.ZipFile(wheel).read(f"uav_depth/core/params/shipped/{name}")
        assert shipped == (ROOT / "deploy" / name).read_bytes(), f"the wheel's {name} is not deploy/{name}"
    entry = [n for n in names if n.endswith("entry_points.txt")]
    assert "uav-depth = uav_depth.cli.main:entry" in zipfile.ZipFile(wheel).read(entry[0]).decode()


def test_import_names():
    import uav_depth.daemon
    import uav_depth.tuning

    assert not hasattr(uav_depth, "__file__") or uav_depth.__file__ is None
    assert Path(uav_depth.daemon.__file__).parent.name == "daemon"
