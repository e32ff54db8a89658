"""The layering contract and the size rules: one room per job, imports pointing one way, nothing waived.

core <- daemon (the on-board runtime), sim (the simulator), tuning <- cli. The
import-linter contracts in pyproject.toml say which room may import which; this
file runs them with no exception allowed, and adds what they cannot say:

- the import graph includes every import statement, late ones inside functions too
  (grimp reads them all), and the imports made by name: a module that calls
  ``importlib.import_module`` (or ``__import__``) imports every project module it
  names in a string literal, the literal argument or a table of names such as the
  command table of :mod:`uav_depth.cli.main`;
- no import cycle anywhere in that graph, and the imports by name point down too;
- the sizes: no module over 400 lines, no function over 80 lines outside tests,
  README at most 200 lines, no page of docs/ over 400 lines besides its generated
  tables, and no comment that waives a limit instead of meeting it.

Each check lists every offender by name and size in its failure message.
"""

from __future__ import annotations

import ast
import functools
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import grimp

from uav_depth.cli.docs import without_generated

ROOT = Path(__file__).resolve().parents[1]
#: package -> its folder (pyproject's package-dir)
ROOMS = {"uav_depth.core": ROOT / "core", "uav_depth.daemon": ROOT / "daemon", "uav_depth.sim": ROOT / "sim",
         "uav_depth.tuning": ROOT / "tuning", "uav_depth.cli": ROOT / "cli"}
#: which rooms each room may import (itself included): the arrows of pyproject's contracts
MAY_IMPORT = {"uav_depth.core": {"uav_depth.core"},
              "uav_depth.daemon": {"uav_depth.core", "uav_depth.daemon"},
              "uav_depth.sim": {"uav_depth.core", "uav_depth.sim"},
              "uav_depth.tuning": {"uav_depth.core", "uav_depth.tuning"},
              "uav_depth.cli": set(ROOMS)}
#: the Python the function rule covers (tests are exempt); the module rule covers tests/ as well
CODE = (*ROOMS.values(), ROOT / "bench")
MAX_MODULE_LINES, MAX_FUNCTION_LINES, MAX_README_LINES, MAX_PAGE_LINES = 400, 80, 200, 400
#: a comment or docstring that excuses a size instead of curing it (Longer than N lines because ...)
WAIVER = re.compile(r"(?i)\b(longer|more) than \d+ lines,? because")
IMPORTERS_BY_NAME = {"import_module", "__import__"}


def _files(folders) -> list[Path]:
    return sorted(p for folder in folders for p in folder.rglob("*.py") if "__pycache__" not in p.parts)


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines())


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


# --- the import graph ---------------------------------------------------------------------------------


def _module_file(module: str, packages: dict[str, Path]) -> Path | None:
    for package, folder in packages.items():
        if module == package or module.startswith(package + "."):
            base = folder.joinpath(*module[len(package) + 1:].split(".")) if module != package else folder
            for candidate in (base.with_suffix(".py"), base / "__init__.py"):
                if candidate.is_file():
                    return candidate
    return None


def imports_by_name(module: str, path: Path, known: set[str]) -> list[tuple[str, int, str]]:
    """(imported module, line, line text) for each project module ``module`` names in a string literal,
    when it imports by name at all (a call of ``import_module`` or ``__import__``)."""
    text = path.read_text()
    tree = ast.parse(text)
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
             and (getattr(n.func, "attr", None) in IMPORTERS_BY_NAME or getattr(n.func, "id", None)
                  in IMPORTERS_BY_NAME)]
    if not calls:
        return []
    lines = text.splitlines()
    named = [(n.value, n.lineno) for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    return sorted({(name, line, lines[line - 1].strip()) for name, line in named if name in known
                   and name != module})


def build_graph(packages: dict[str, Path]) -> tuple[grimp.ImportGraph, list[tuple[str, str, int, str]]]:
    """grimp's graph of ``packages`` (every import statement, late ones included) with the imports by
    name added; returns it and the added imports (importer, imported, line, line text)."""
    graph = grimp.build_graph(*packages, include_external_packages=False, cache_dir=None)
    known = set(graph.modules)
    added = []
    for module in sorted(known):
        path = _module_file(module, packages)
        for imported, line, contents in (imports_by_name(module, path, known) if path else []):
            graph.add_import(importer=module, imported=imported, line_number=line, line_contents=contents)
            added.append((module, imported, line, contents))
    return graph, added


def cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each a cycle of imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(m: str) -> None:
        index[m] = low[m] = counter[0]
        counter[0] += 1
        stack.append(m)
        on.add(m)
        for n in sorted(graph.find_modules_directly_imported_by(m)):
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

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10000))
    try:
        for m in sorted(graph.modules):
            if m not in index:
                visit(m)
    finally:
        sys.setrecursionlimit(limit)
    return found


def describe_cycle(graph: grimp.ImportGraph, component: list[str]) -> str:
    """Every import inside a cycle, with its line: what to cut."""
    inside = set(component)
    edges = []
    for m in component:
        for n in sorted(graph.find_modules_directly_imported_by(m) & inside):
            for d in graph.get_import_details(importer=m, imported=n):
                edges.append(f"  {m} -> {n} (line {d['line_number']}: {d['line_contents']})")
    return "\n".join(edges)


@functools.cache
def project_graph() -> tuple[grimp.ImportGraph, list[tuple[str, str, int, str]]]:
    """:func:`build_graph` of the five rooms, built once per session (the tests only read it)."""
    return build_graph(ROOMS)


def _room(module: str) -> str:
    return next(room for room in ROOMS if module == room or module.startswith(room + "."))


def test_import_linter_contracts_are_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    out = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "0 broken" in out.stdout


def test_the_contracts_waive_nothing():
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    waived = [f"{c['name']}: {imp}" for c in contracts for imp in c.get("ignore_imports", [])]
    assert waived == [], "pyproject's import-linter contracts ignore imports (none may):\n" + "\n".join(waived)
    assert {room for c in contracts for room in c["source_modules"]} == set(ROOMS) - {"uav_depth.cli"}


def test_no_import_cycle_late_and_by_name_imports_included():
    graph, _ = project_graph()
    found = cycles(graph)
    assert found == [], "import cycles:\n" + "\n".join(describe_cycle(graph, c) for c in found)


def test_imports_by_name_point_down():
    _, added = project_graph()
    assert ("uav_depth.cli.main", "uav_depth.cli.commands.run") in {(a, b) for a, b, _, _ in added}
    up = [f"{a} -> {b} (line {line}: {text})" for a, b, line, text in added if _room(b) not in MAY_IMPORT[_room(a)]]
    assert up == [], "imports by name against the layering:\n" + "\n".join(up)


def test_the_exit_codes_are_a_leaf():
    """The commands return them and cli.main loads the commands: they import nothing, so nothing cycles through them."""
    graph, _ = project_graph()
    assert graph.find_modules_directly_imported_by("uav_depth.cli.exit_codes") == set()
    importers = graph.find_modules_that_directly_import("uav_depth.cli.main")
    assert not {m for m in importers if m.startswith("uav_depth.cli.commands.")}, importers


def _package(tmp_path, monkeypatch, files: dict[str, str]) -> dict[str, Path]:
    pkg = tmp_path / "cyc"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name, text in files.items():
        (pkg / name).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    return {"cyc": pkg}


def test_the_cycle_check_sees_a_late_import(tmp_path, monkeypatch):
    packages = _package(tmp_path, monkeypatch, {"a.py": "def f():\n    from cyc import b\n",
                                                "b.py": "from cyc import a\n"})
    graph, _ = build_graph(packages)
    assert cycles(graph) == [["cyc.a", "cyc.b"]]
    assert "cyc.a -> cyc.b (line 2: from cyc import b)" in describe_cycle(graph, ["cyc.a", "cyc.b"])


def test_the_cycle_check_sees_an_import_by_name(tmp_path, monkeypatch):
    """The shape main had: a table of command modules loaded by name, each importing the table's module back."""
    packages = _package(tmp_path, monkeypatch, {
        "main.py": "import importlib\nTABLE = {'x': 'cyc.cmd'}\n\ndef run(name):\n"
                   "    return importlib.import_module(TABLE[name])\n\nCODE = 1\n",
        "cmd.py": "def run():\n    from cyc.main import CODE\n    return CODE\n",
        "direct.py": "from importlib import import_module\nmod = import_module('cyc.leaf')\n",
        "leaf.py": "import cyc.direct\n",
        "logs.py": "NAME = 'cyc.leaf'\n",         # names a module without importing by name: no import
    })
    graph, added = build_graph(packages)
    assert cycles(graph) == [["cyc.cmd", "cyc.main"], ["cyc.direct", "cyc.leaf"]]
    assert [(a, b, line) for a, b, line, _ in added] == [("cyc.direct", "cyc.leaf", 2), ("cyc.main", "cyc.cmd", 2)]


# --- sizes --------------------------------------------------------------------------------------------


def long_functions(paths) -> list[str]:
    """``path:line name (N lines)`` of every function or method over the limit, decorators counted."""
    out = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                n = node.end_lineno - first + 1
                if n > MAX_FUNCTION_LINES:
                    out.append(f"{_rel(path)}:{node.lineno} {node.name} ({n} lines)")
    return out


def test_no_module_over_400_lines_tests_included():
    sizes = [(_lines(p), _rel(p)) for p in _files((*CODE, ROOT / "tests"))]
    too_long = [f"{name} ({n} lines)" for n, name in sorted(sizes, reverse=True) if n > MAX_MODULE_LINES]
    assert too_long == [], f"modules over {MAX_MODULE_LINES} lines (split them by job):\n" + "\n".join(too_long)


def test_no_function_over_80_lines_outside_tests():
    too_long = long_functions(_files(CODE))
    assert too_long == [], f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(too_long)


def test_no_comment_waives_a_limit():
    waivers = [f"{_rel(p)}:{i} ({_lines(p)} lines): {line.strip()}" for p in _files((*CODE, ROOT / "tests"))
               for i, line in enumerate(p.read_text().splitlines(), 1) if WAIVER.search(line)]
    assert waivers == [], "a limit is met, not excused:\n" + "\n".join(waivers)


def test_the_size_checks_see_what_they_must(tmp_path):
    long_def = tmp_path / "m.py"
    body = lambda indent: "".join(f"{indent}x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))  # noqa: E731
    long_def.write_text(f"def ok():\n{body('    ')}\n\nclass C:\n    @staticmethod\n    def long():\n"
                        f"{body(' ' * 8)}")     # ok: 80 lines; long: 81 with its decorator
    assert long_functions([long_def]) == [f"{long_def}:85 long (81 lines)"]
    assert WAIVER.search("Longer than 400 lines" + " because it is the one schema.")   # split: not a waiver here
    assert WAIVER.search("# more than 80 lines" + ", because the table reads as one")
    assert not WAIVER.search("no module over 400 lines")


def test_readme_at_most_200_lines():
    n = _lines(ROOT / "README.md")
    assert n <= MAX_README_LINES, f"README.md ({n} lines) is over {MAX_README_LINES}"


def test_no_docs_page_over_400_lines_but_generated_tables():
    sizes = [(len(without_generated(p.read_text()).splitlines()), _rel(p)) for p in (ROOT / "docs").rglob("*.md")]
    too_long = [f"{name} ({n} lines)" for n, name in sorted(sizes, reverse=True) if n > MAX_PAGE_LINES]
    assert too_long == [], (f"docs pages over {MAX_PAGE_LINES} lines, generated tables not counted:\n"
                            + "\n".join(too_long))
