"""The run store: an Optuna RDB storage holding every evaluation of a tuning study.

Every optimiser (the paper's GA too) writes into an ordinary Optuna study, so
``optuna-dashboard sqlite:///STORE`` shows a run live and ``optuna.load_study``
reads it. One study per store file, named :data:`STUDY_NAME` (a k-fold run adds one per further fold,
:func:`fold_study_name`):

- each candidate evaluated is one trial, added as soon as its evaluation arrives
  (a killed run loses at most the candidates still computing): COMPLETE with the
  fitness as its value, or FAIL; its tuned keys as Optuna params (schema bounds as
  distributions); user attributes ``key`` (the cache key: a hash of parameters,
  frame digest, fitness and evaluator version), ``params`` (the whole parameter
  set), and the evaluation itself (``status``, ``value``, ``metrics``,
  ``per_frame``, ``ms``, ``reason``, ``seconds``);
- study user attributes: ``config`` (the study's resolved configuration, checked
  by ``--resume``) and ``proposals/RUN/GENERATION`` (which keys that generation
  proposed, with their utilities: the optimiser's trajectory).

Resume works by replaying the optimiser from its seed: every proposal whose key
is already stored is answered from the store, so the replay retraces the killed
run exactly and carries on from where it stopped. The evaluation is read back
from the JSON user attributes (Python's float repr round-trips every double), so
a stored fitness is bit-identical to the computed one.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from uav_depth.core.errors import FileFormatError
from uav_depth.core.params import SPEC_BY_KEY

from uav_depth.tuning.objective import Evaluation

#: The Optuna study of a store (one per file).
STUDY_NAME = "uav-depth-tune"
_PROPOSALS = "proposals/"


def fold_study_name(fold: int) -> str:
    """The study of fold ``fold`` (0-based) of a k-fold run: fold 0 is the ordinary :data:`STUDY_NAME`."""
    return STUDY_NAME if fold == 0 else f"{STUDY_NAME}-fold{fold + 1}"


#: How long a write waits for a reader's lock on a SQLite store (optuna-dashboard, ``optuna studies``, a test
#: polling the trial count) before failing: SQLite's own default is 5 s, which a loaded machine exceeds.
SQLITE_BUSY_TIMEOUT_S = 60.0


def _engine_kwargs(url: str) -> dict:
    return {"connect_args": {"timeout": SQLITE_BUSY_TIMEOUT_S}} if url.startswith("sqlite:") else {}


def storage_url(path: str | os.PathLike[str]) -> str:
    """An Optuna storage URL: ``path`` itself when it is one (``sqlite:///...``, ``postgresql://...``),
    else a SQLite file at ``path``."""
    text = str(path)
    if "://" in text:
        return text
    return f"sqlite:///{Path(text).resolve()}"


def _distribution(key: str):
    import optuna

    spec = SPEC_BY_KEY.get(key)
    if spec is None:
        return None
    if spec.kind is bool:
        return optuna.distributions.CategoricalDistribution((False, True))
    if spec.choices is not None:
        return optuna.distributions.CategoricalDistribution(tuple(spec.choices))
    if spec.kind is int and spec.lo is not None and spec.hi is not None:
        return optuna.distributions.IntDistribution(int(spec.lo), int(spec.hi))
    if spec.kind is float and spec.lo is not None and spec.hi is not None:
        return optuna.distributions.FloatDistribution(float(spec.lo), float(spec.hi))
    return None


def _get(params: Mapping[str, Any], key: str) -> Any:
    section, name = key.split(".", 1)
    return params.get(section, {}).get("lambda" if name == "lambda" else name)


class RunStore:
    """The Optuna study at ``path`` (a file, an Optuna storage URL, or ":memory:" for a throw-away run).

    ``study_name``: :data:`STUDY_NAME`, or :func:`fold_study_name` for the later folds of a k-fold run
    (one store holds every fold's study).

    ``direction``: "minimize" or "maximize" (the fitness's), used when the study is
    created; ``keys``: the tuned schema keys, recorded as each trial's Optuna params.
    """

    def __init__(self, path: str | os.PathLike[str] = ":memory:", direction: str = "minimize",
                 keys: Sequence[str] = (), study_name: str = STUDY_NAME):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.path = str(path)
        memory = self.path == ":memory:"
        self.url = None if memory else storage_url(path)
        if not memory and "://" not in self.path:
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
            _refuse_old_format(Path(self.path))
        for attempt in range(OPEN_RETRIES + 1):
            try:
                self.storage = optuna.storages.InMemoryStorage() if memory else optuna.storages.RDBStorage(
                    self.url, engine_kwargs=_engine_kwargs(self.url))
                self.study = optuna.create_study(storage=self.storage, study_name=study_name, direction=direction,
                                                 load_if_exists=True)
                break
            except Exception as exc:  # SQLAlchemy / Optuna raise many kinds for a file that is not a store
                if attempt < OPEN_RETRIES and _opened_elsewhere(exc):
                    time.sleep(OPEN_RETRY_S)
                    continue
                raise FileFormatError(f"{self.path}: not a usable run store ({type(exc).__name__}: {exc})") from exc
        self._dists = {k: d for k in keys if (d := _distribution(k)) is not None}
        self._rows: dict[str, tuple[dict[str, Any], Evaluation]] = {}
        self._order: list[str] = []
        for t in self.study.get_trials(deepcopy=False):
            key = t.user_attrs.get("key")
            if key is not None and key not in self._rows:
                self._rows[key] = (t.user_attrs["params"], _attrs_to_eval(t.user_attrs))
                self._order.append(key)

    def close(self) -> None:
        if self.url is not None:
            self.storage.remove_session()
            self.storage.engine.dispose()

    def __enter__(self) -> "RunStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- configuration ------------------------------------------------------------------------------------------

    def config(self) -> dict[str, Any] | None:
        return self.study.user_attrs.get("config")

    def set_config(self, config: Mapping[str, Any]) -> None:
        self.study.set_user_attr("config", json.loads(json.dumps(config, sort_keys=True, default=str)))

    # -- evaluations --------------------------------------------------------------------------------------------

    def get(self, key: str) -> Evaluation | None:
        row = self._rows.get(key)
        return None if row is None else row[1]

    def put(self, key: str, params: Mapping[str, Any], params_hash: str | None, ev: Evaluation) -> None:
        """Add the evaluation of ``key`` as one trial (once: a key already stored is left as it is)."""
        import optuna

        if key in self._rows:
            return
        clean = json.loads(json.dumps(params, sort_keys=True, default=str))
        attrs = {"key": key, "params_hash": params_hash, "params": clean, "status": ev.status, "value": ev.value,
                 "metrics": dict(ev.metrics), "per_frame": list(ev.per_frame), "ms": ev.ms, "reason": ev.reason,
                 "seconds": ev.seconds}
        ok = ev.ok and math.isfinite(ev.value)
        values = {k: _get(clean, k) for k in self._dists} if not clean.get("invalid") else {}
        values = {k: v for k, v in values.items() if v is not None and _fits(self._dists[k], v)}
        trial = optuna.trial.create_trial(
            state=optuna.trial.TrialState.COMPLETE if ok else optuna.trial.TrialState.FAIL,
            value=ev.value if ok else None, params=values, distributions={k: self._dists[k] for k in values},
            user_attrs=attrs)
        self.study.add_trial(trial)
        self._rows[key] = (clean, ev)
        self._order.append(key)

    def count(self) -> int:
        return len(self._order)

    def evaluations(self, keys: Iterable[str] | None = None) -> Iterator[tuple[str, dict[str, Any], Evaluation]]:
        """(key, params, evaluation) rows, oldest first; only ``keys`` when given."""
        wanted = None if keys is None else set(keys)
        for key in list(self._order):
            if wanted is None or key in wanted:
                params, ev = self._rows[key]
                yield key, params, ev

    # -- the optimiser's trajectory -----------------------------------------------------------------------------

    def put_trials(self, run: int, generation: int, keys: list[str], utilities: list[float]) -> None:
        self.study.set_user_attr(f"{_PROPOSALS}{run}/{generation}", [[k, u] for k, u in zip(keys, utilities)])

    def trials(self) -> list[tuple[int, int, int, str, float | None]]:
        """Every (run, generation, index, key, utility) proposal, in order (None utility: failed)."""
        out = []
        for name, rows in self.study.user_attrs.items():
            if name.startswith(_PROPOSALS):
                run, gen = (int(x) for x in name[len(_PROPOSALS):].split("/"))
                out += [(run, gen, i, k, None if u is None or not math.isfinite(u) else u)
                        for i, (k, u) in enumerate(rows)]
        return sorted(out, key=lambda r: r[:3])


def _fits(dist, value: Any) -> bool:
    try:
        return bool(dist._contains(dist.to_internal_repr(value)))
    except (ValueError, TypeError):
        return False


#: Another process opening the same new store at the same moment (optuna-dashboard, ``optuna studies``, a
#: script reading it through Optuna) creates Optuna's schema too: SQLite then refuses one side's CREATE TABLE
#: ("table studies already exists"), or its schema-version row ("UNIQUE constraint failed:
#: alembic_version.version_num"), or holds the file locked for a moment (measured: 2 runs in 8 with a reader
#: polling the store as it started). Opening again finds the schema made.
OPEN_RETRIES = 10
OPEN_RETRY_S = 0.1


def _opened_elsewhere(exc: BaseException) -> bool:
    """True for the errors of a store whose schema another process is creating at this moment."""
    kind, text = type(exc).__name__, str(exc)
    return ((kind == "OperationalError" and ("already exists" in text or "database is locked" in text))
            or (kind == "IntegrityError" and "alembic_version" in text))


def _refuse_old_format(path: Path) -> None:
    """Stores of uav-depth < 0.x were plain SQLite tables that Optuna's schema collides with."""
    import sqlite3

    if not path.exists() or path.stat().st_size == 0:
        return
    try:
        with sqlite3.connect(path) as db:
            tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError as exc:
        raise FileFormatError(f"{path}: not a usable run store ({exc})") from exc
    if "evaluations" in tables:
        raise FileFormatError(f"{path}: a run store of an older uav-depth (not an Optuna storage); "
                              "choose another --store")


def _attrs_to_eval(a: Mapping[str, Any]) -> Evaluation:
    return Evaluation(a["status"], float(a["value"]) if a["value"] is not None else math.nan, a["metrics"],
                      tuple(a["per_frame"]), float(a["ms"]) if a["ms"] is not None else math.nan, a["reason"],
                      float(a["seconds"] or 0.0))
