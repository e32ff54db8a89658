"""Issue 44's faults and every condition of the wire contract, against the real daemon process: one row per fault.

Each case starts ``uav-depth`` as a subprocess (``run``, ``run --check``, ``params check``,
``evaluate``, ``tune``; a synthetic or replay source; config and files in a temporary
directory), drives one fault from outside (a file, a signal, a pymavlink peer or a bare UDP
peer on loopback) and prints what was expected, what was observed and whether it passed.
Waits end on what the peer received or the daemon logged, with long deadlines, so the
table holds on a loaded machine.

- files (bench/fault_files.py): uniqueness 100, a YAML alias bomb, an oversize file and a
  FIFO as the parameter file, at start-up (``run`` and ``run --check``) and on SIGHUP (the
  last good parameters kept, no gap in the stream over 500 ms); a 100000 px scene; an
  unreachable serial link and a udpin port in use in ``run --check``; ``--set nosuch.key``.
- link, scene, signals (bench/fault_link.py): udpin taken by a stranger's HEARTBEAT, a
  replayed signed HEARTBEAT, a wrong-key flood, a TCP peer that stops reading for 10 s, a
  blank noisy scene, SIGINT/SIGTERM early in start-up, nothing after "stopping".
- the wire (tests/wire_scenarios.py, shared with tests/daemon/test_wire_conditions.py): one
  row per ``Condition`` of daemon/link/conditions.py, its expectation read from the contract;
  "parameters unusable" is also issue 44 item 2 (a missing parameter file).

Not driven from outside, so tested in-process instead: the link's I/O thread dying (item 3,
tests/daemon/test_health.py), the 49.7-day wrap and the outlier gate's thread (item 8,
tests/daemon/link/test_contract.py, tests/daemon/test_service.py).

    nice -n 10 .venv/bin/python bench/faults.py [--only WORD ...]

Exit status 1 when any row fails. About 3 minutes (at load 15 on two cores).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO / "tests"), str(REPO / "tests" / "daemon"), str(REPO / "bench")]

import fault_files  # noqa: E402
import fault_link  # noqa: E402
from wire_rows import Row, expected, judge  # noqa: E402
from wire_scenarios import SCENARIOS  # noqa: E402

from uav_depth.daemon.link.conditions import Condition  # noqa: E402


def wire(d: Path) -> list[Row]:
    """One row per Condition of the contract, each scenario run once; item 2 (no parameter file) besides."""
    rows: dict[Condition, Row] = {}
    for scenario in SCENARIOS:
        (d / scenario.name).mkdir()
        try:
            got = scenario.run(d / scenario.name)
        except AssertionError as exc:
            why = f"scenario {scenario.name} failed: {str(exc).splitlines()[0][:160]}"
            rows.update({c: Row(f"wire: {c.value}", str(expected(c)), why, False) for c in scenario.conditions})
            continue
        rows.update({c: judge(c, got[c]) for c in scenario.conditions})
    unusable = rows[Condition.PARAMS_UNUSABLE]
    item_2 = Row("parameter file missing (item 2)", unusable.expected, unusable.observed, unusable.ok)
    return [rows[c] for c in Condition] + [item_2]


CASES = [*fault_files.START_UP, fault_files.reloads, *fault_link.CASES, wire]


def _name(case) -> str:
    return getattr(case, "__name__", "") + " " + (case.__doc__ or "")


def run_case(case, root: Path) -> list[Row]:
    d = Path(tempfile.mkdtemp(prefix="case-", dir=root))
    try:
        return case(d)
    except Exception as exc:     # a case that cannot finish is a failed row, and the table goes on
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        return [Row(_name(case).split(" ")[0] or "case", "the case runs to its end", f"{type(exc).__name__}: "
                    f"{first[:200]}", False)]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def print_table(rows: list[Row]) -> None:
    print("| fault | expected | observed | pass |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {_cell(r.name)} | {_cell(r.expected)} | {_cell(r.observed)} | {'yes' if r.ok else 'NO'} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="*", default=[], help="run the cases whose function name or docstring has a word")
    args = ap.parse_args()
    cases = [c for c in CASES if not args.only or any(w in _name(c) for w in args.only)]
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    rows: list[Row] = []
    # pymavlink prints its TCP reconnects on stdout: they go to stderr, the table alone to stdout
    with tempfile.TemporaryDirectory(prefix="uav-depth-faults-") as root, contextlib.redirect_stdout(sys.stderr):
        for case in cases:
            got = run_case(case, Path(root))
            rows += got
            for r in got:
                print(f"{'pass' if r.ok else 'FAIL'}: {r.name}", file=sys.stderr, flush=True)
    print_table(rows)
    failed = [r.name for r in rows if not r.ok]
    print(f"\n{len(rows) - len(failed)}/{len(rows)} rows pass in {time.monotonic() - t0:.0f} s; load average "
          f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on {os.cpu_count()} CPUs")
    if failed:
        print("failed: " + "; ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
