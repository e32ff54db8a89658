"""The run store: one SQLite file holding every evaluation of a tuning study.

Tables:

- ``meta``: the study's resolved configuration (JSON), written once; ``--resume``
  checks it against the new invocation.
- ``evaluations``: the cache, keyed by a hash of (parameters, frame digest,
  fitness, evaluator version): status, fitness, extra metrics, ms per frame,
  reason of a failure, the parameters as JSON. Each row is committed as soon as
  its evaluation arrives, so a killed run loses at most the candidates that were
  still computing.
- ``trials``: which candidate each (run, generation, index) proposed.

Resume works by replaying the optimiser from its seed: every proposal whose key
is already here is answered from the store, so the replay retraces the killed
run exactly and carries on from where it stopped. Floats are stored as SQLite
REAL (IEEE doubles), so a stored fitness is bit-identical to the computed one.
"""

from __future__ import annotations

import json
import math
import sqlite3
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

from uav_depth.core.errors import FileFormatError

from uav_depth.tuning.objective import Evaluation

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS evaluations (
    key TEXT PRIMARY KEY, params_hash TEXT, params TEXT NOT NULL, status TEXT NOT NULL, value REAL,
    metrics TEXT NOT NULL, per_frame TEXT NOT NULL, ms REAL, reason TEXT, seconds REAL, created REAL);
CREATE TABLE IF NOT EXISTS trials (
    run INTEGER, generation INTEGER, idx INTEGER, key TEXT NOT NULL, utility REAL,
    PRIMARY KEY (run, generation, idx));
"""


def _num(x: float | None) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


class RunStore:
    """SQLite store at ``path`` (":memory:" for a throw-away run)."""

    def __init__(self, path: str | Path = ":memory:"):
        self.path = str(path)
        if self.path != ":memory:":
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        try:
            self.db = sqlite3.connect(self.path)
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.executescript(SCHEMA)
        except sqlite3.DatabaseError as exc:
            raise FileFormatError(f"{self.path}: not a usable run store ({exc})") from exc

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> "RunStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- configuration ------------------------------------------------------------------------------------------

    def config(self) -> dict[str, Any] | None:
        row = self.db.execute("SELECT value FROM meta WHERE key = 'config'").fetchone()
        return None if row is None else json.loads(row[0])

    def set_config(self, config: Mapping[str, Any]) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO meta VALUES ('config', ?)", (json.dumps(config, sort_keys=True),))

    def put_meta(self, key: str, value: Any) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value, default=str)))

    def get_meta(self, key: str) -> Any:
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else json.loads(row[0])

    # -- evaluations --------------------------------------------------------------------------------------------

    def get(self, key: str) -> Evaluation | None:
        row = self.db.execute("SELECT status, value, metrics, per_frame, ms, reason, seconds FROM evaluations "
                              "WHERE key = ?", (key,)).fetchone()
        return None if row is None else _row_to_eval(row)

    def put(self, key: str, params: Mapping[str, Any], params_hash: str | None, ev: Evaluation) -> None:
        with self.db:
            self.db.execute(
                "INSERT OR REPLACE INTO evaluations VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (key, params_hash, json.dumps(params, sort_keys=True, default=str), ev.status, _num(ev.value),
                 json.dumps(dict(ev.metrics)), json.dumps(list(ev.per_frame)), _num(ev.ms), ev.reason, ev.seconds,
                 time.time()))

    def count(self) -> int:
        return int(self.db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0])

    def evaluations(self, keys: Iterable[str] | None = None) -> Iterator[tuple[str, dict[str, Any], Evaluation]]:
        """(key, params, evaluation) rows, oldest first; only ``keys`` when given."""
        rows = self.db.execute("SELECT key, params, status, value, metrics, per_frame, ms, reason, seconds "
                               "FROM evaluations ORDER BY rowid").fetchall()
        wanted = None if keys is None else set(keys)
        for row in rows:
            if wanted is None or row[0] in wanted:
                yield row[0], json.loads(row[1]), _row_to_eval(row[2:])

    # -- trials -------------------------------------------------------------------------------------------------

    def put_trials(self, run: int, generation: int, keys: list[str], utilities: list[float]) -> None:
        with self.db:
            self.db.executemany("INSERT OR REPLACE INTO trials VALUES (?, ?, ?, ?, ?)",
                                [(run, generation, i, k, _num(u)) for i, (k, u) in enumerate(zip(keys, utilities))])

    def trials(self) -> list[tuple[int, int, int, str, float | None]]:
        """Every (run, generation, index, key, utility) proposal, in order (None utility: failed)."""
        return [tuple(r) for r in self.db.execute("SELECT run, generation, idx, key, utility FROM trials "
                                                   "ORDER BY run, generation, idx")]

    def trial_count(self) -> int:
        return int(self.db.execute("SELECT COUNT(*) FROM trials").fetchone()[0])


def _row_to_eval(row) -> Evaluation:
    status, value, metrics, per_frame, ms, reason, seconds = row
    return Evaluation(status, math.nan if value is None else float(value), json.loads(metrics),
                      tuple(json.loads(per_frame)), math.nan if ms is None else float(ms), reason,
                      float(seconds or 0.0))
