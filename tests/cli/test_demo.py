"""demo flies what flies (the flight parameters for its resolution) and prints branch distances against the
truth; long phases print progress on a terminal."""

import io
import re

from uav_depth.core.params.flight import flight_params
from uav_depth.cli.progress import progress_line
from uav_depth.cli.main import main


def test_demo_scores_the_flight_parameters_and_prints_branch_distances(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "d"), "--frames", "2"]) == 0
    out = capsys.readouterr().out
    assert f"hash {flight_params(700.0, 0.063).hash()}" in out
    rows = [line for line in out.splitlines() if line.startswith("d/")]
    assert len(rows) == 2
    for row in rows:
        fields = row.split()
        truth = float(fields[1])
        assert 0.3 < truth < 2.5
        if fields[2] != "none":
            # the error printed is the measured distance's against the truth (both rounded to 1 mm)
            assert abs(abs(float(fields[2]) - truth) / truth * 100 - float(fields[3])) < 0.2
        else:
            # ... and a frame without a distance says why, as the daemon would (seed 0's second frame: the floor)
            assert re.search(rf"^  {fields[0]}: (no measurement|too close): \S", out, re.M), out
    assert any(row.split()[2] == "none" for row in rows), "seed 0 has a frame below the quality floor: the case above"
    assert re.search(r"branch distance: median error [\d.]+% over 2 frames", out)


class Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_lines_on_a_terminal_only(monkeypatch):
    import sys

    tty = Tty()
    monkeypatch.setattr(sys, "stderr", tty)
    p = progress_line("rendered", every_s=0.0)
    p(1, 3), p(3, 3)
    assert tty.getvalue().splitlines() == ["  rendered 1/3", "  rendered 3/3"]
    pipe = io.StringIO()
    monkeypatch.setattr(sys, "stderr", pipe)
    progress_line("rendered", every_s=0.0)(1, 3)
    assert pipe.getvalue() == ""
