"""The layering contract: one room per job, imports pointing one way.

core <- daemon (the on-board runtime), sim (the simulator), tuning <- cli. The
import-linter contracts in pyproject.toml say which room may import which; this
file runs them, and adds what they cannot say: no import cycle anywhere (late
imports inside functions included: grimp reads every import statement), the two
seams (the simulator's frame-source interface, the tuner's ranging) import only
the core, and no module grows past 400 lines without saying why.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ("uav_depth.core", "uav_depth.daemon", "uav_depth.sim", "uav_depth.tuning", "uav_depth.cli")
FOLDERS = ("core", "daemon", "sim", "tuning", "cli")
#: What the higher rooms share with the runtime lives in the core: the frame interface and the ranging.
SEAMS = ("uav_depth.core.frames", "uav_depth.core.ranging")
MAX_LINES = 400


def _graph():
    return grimp.build_graph(*ROOMS, include_external_packages=False, cache_dir=None)


def test_import_linter_contracts_are_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    out = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "0 broken" in out.stdout


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each a cycle of imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(m: str) -> None:
        index[m] = low[m] = counter[0]
        counter[0] += 1
        stack.append(m)
        on.add(m)
        for n in graph.find_modules_directly_imported_by(m):
            if n not in index:
                visit(n)
                low[m] = min(low[m], low[n])
            elif n in on:
                low[m] = min(low[m], index[n])
        if low[m] == index[m]:
            comp = []
            while True:
                n = stack.pop()
                on.discard(n)
                comp.append(n)
                if n == m:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for m in sorted(graph.modules):
        if m not in index:
            visit(m)
    return found


def test_no_import_cycles_late_imports_included():
    assert _cycles(_graph()) == []


def test_cycle_detector_finds_a_cycle(tmp_path, monkeypatch):
    pkg = tmp_path / "cyc"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from cyc import b\n")   # a late import closes the loop
    (pkg / "b.py").write_text("from cyc import a\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert _cycles(grimp.build_graph("cyc", cache_dir=None)) == [["cyc.a", "cyc.b"]]


def test_seams_import_only_the_core():
    graph = _graph()
    for seam in SEAMS:
        above = {m for m in graph.find_upstream_modules(seam) if not m.startswith("uav_depth.core")}
        assert above == set(), f"{seam} imports {sorted(above)}: a seam may import only uav_depth.core"


def test_no_module_over_400_lines_without_a_reason():
    too_long = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            if text.count("\n") > 400 and "Longer than 400 lines because" not in text[:4000]:
                too_long.append(f"{path.relative_to(ROOT)} ({text.count(chr(10))} lines)")
    assert too_long == [], "say why in the module docstring ('Longer than 400 lines because ...') or split it"
