"""synth and demo refuse to overwrite an existing session without --overwrite (one line, exit 73)."""

import subprocess
import sys

import pytest

from uav_depth.cli.exit_codes import EXIT_CANTCREAT
from uav_depth.core.errors import OutputExistsError
from uav_depth.core.session import Session, prepare_output

SMALL = ("--width", "160", "--height", "120", "--focal-px", "100")


def cli(*args):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *args], capture_output=True, text=True,
                          timeout=300)


def test_synth_twice_is_refused_then_replaced_with_overwrite(tmp_path):
    out = tmp_path / "s"
    assert cli("synth", str(out), "--frames", "3", *SMALL).returncode == 0
    again = cli("synth", str(out), "--frames", "1", "--width", "320", "--height", "240", "--focal-px", "200")
    assert again.returncode == EXIT_CANTCREAT
    assert again.stderr.count("\n") == 1 and "--overwrite" in again.stderr and "3 frames" in again.stderr
    assert len(Session(out).frames()) == 3                     # untouched
    done = cli("synth", str(out), "--frames", "1", "--width", "320", "--height", "240", "--focal-px", "200",
               "--overwrite")
    assert done.returncode == 0, done.stderr
    s = Session(out)
    assert len(s.frames()) == 1 and s.calibration().width == 320   # no old frame or calibration left


def test_synth_onto_a_file_is_one_line(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    out = cli("synth", str(f), "--frames", "1", *SMALL)
    assert out.returncode == EXIT_CANTCREAT and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1 and "is a file" in out.stderr


def test_demo_refuses_an_existing_session(tmp_path):
    out = tmp_path / "d"
    assert cli("synth", str(out), "--frames", "1", *SMALL).returncode == 0
    demo = cli("demo", "--out", str(out))
    assert demo.returncode == EXIT_CANTCREAT and "--overwrite" in demo.stderr
    assert len(Session(out).frames()) == 1


def test_prepare_output_rules(tmp_path):
    assert prepare_output(tmp_path / "new") == tmp_path / "new"
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not a session"):
        prepare_output(tmp_path / "other", overwrite=True)
    assert (tmp_path / "other" / "notes.txt").exists()
