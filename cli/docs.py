"""The documentation's generated tables, from the code that defines what they describe.

A page marks a generated table with ``<!-- generated: NAME ... -->`` and
``<!-- end generated -->``; :data:`TABLES` maps NAME to the function that writes
it. ``python -m uav_depth.cli.docs --write`` refreshes every marked table in
``docs/``; without ``--write`` it lists the stale ones and exits 1
(tests/test_docs.py checks the same).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import Callable


def commands_table() -> str:
    """Every subcommand with its usage line and help, from the parser itself."""
    from uav_depth.cli.main import COMMANDS, build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rows = ["| command | what it does |", "|---|---|"]
    for name, (_, help_text) in COMMANDS.items():
        usage = " ".join(sub.choices[name].format_usage().split())[len("usage: "):].replace(" [-h]", "")
        rows.append(f"| `{usage}` | {help_text} |")
    return "\n".join(rows)


def params_table() -> str:
    from uav_depth.core.params import params_table_markdown

    return params_table_markdown()


def wire_conditions() -> str:
    from uav_depth.daemon.link.conditions import conditions_table_markdown

    return conditions_table_markdown()


def config_reference() -> str:
    from uav_depth.cli.sources import SOURCES
    from uav_depth.daemon.config import reference_markdown

    return reference_markdown(SOURCES)


#: marker name -> the function that writes the table
TABLES: dict[str, Callable[[], str]] = {
    "commands": commands_table,
    "params_table": params_table,
    "config_reference": config_reference,
    "wire_conditions": wire_conditions,
}

_BLOCK = re.compile(r"(<!-- generated: (\w+)[^>]*-->\n)(.*?)(\n<!-- end generated -->)", re.S)


def refresh(text: str) -> str:
    """``text`` with every generated block rewritten from the code (unknown names are errors)."""
    def repl(m: re.Match) -> str:
        name = m.group(2)
        if name not in TABLES:
            raise KeyError(f"unknown generated table {name!r} (known: {', '.join(TABLES)})")
        return m.group(1) + TABLES[name]() + m.group(4)
    return _BLOCK.sub(repl, text)


def without_generated(text: str) -> str:
    """``text`` with the body of every generated block left out: what was written by hand."""
    return _BLOCK.sub(lambda m: m.group(1) + m.group(4), text)


def blocks(text: str) -> list[str]:
    """Names of the generated blocks in ``text``."""
    return [m.group(2) for m in _BLOCK.finditer(text)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uav_depth.cli.docs", description=__doc__.split("\n")[0])
    ap.add_argument("--docs", type=Path, default=Path("docs"), help="the docs folder (default: docs)")
    ap.add_argument("--write", action="store_true", help="rewrite stale tables instead of listing them")
    args = ap.parse_args(argv)
    stale = []
    for page in sorted(args.docs.rglob("*.md")):
        text = page.read_text()
        new = refresh(text)
        if new != text:
            stale.append(str(page))
            if args.write:
                page.write_text(new)
    for page in stale:
        print(("rewrote " if args.write else "stale: ") + page)
    return 0 if args.write or not stale else 1


if __name__ == "__main__":
    sys.exit(main())
