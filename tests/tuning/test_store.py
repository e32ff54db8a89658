"""The run store (uav_depth.tuning.store) opened by several processes at once, as a live run and optuna-dashboard do."""

import multiprocessing as mp

import optuna

from uav_depth.tuning.store import STUDY_NAME, RunStore, storage_url


def _open_store(path, barrier, errors):
    barrier.wait()
    try:
        RunStore(path).close()
    except Exception as exc:          # the failure this test is about: report it to the parent
        errors.put(f"RunStore: {type(exc).__name__}: {exc}"[:300])


def _read_store(path, barrier, errors):
    """What optuna-dashboard does: open the storage through Optuna (it creates the schema if it is missing)."""
    barrier.wait()
    try:
        storage = optuna.storages.RDBStorage(storage_url(path))
        storage.get_all_studies()
    except Exception as exc:
        errors.put(f"reader: {type(exc).__name__}: {exc}"[:300])


def test_a_new_store_opens_while_another_process_opens_it_too(tmp_path):
    """Two runs and two readers open the same new store at the same moment, 5 times over: the tuner used to exit 1
    ("not a usable run store: table studies already exists") when a reader created Optuna's schema beside it."""
    ctx = mp.get_context("spawn")
    errors = ctx.Queue()
    for round_ in range(5):
        path = tmp_path / f"store{round_}.sqlite"
        barrier = ctx.Barrier(4)
        procs = [ctx.Process(target=_open_store, args=(path, barrier, errors)) for _ in range(2)]
        procs += [ctx.Process(target=_read_store, args=(path, barrier, errors)) for _ in range(2)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(timeout=120)
            assert p.exitcode == 0
        got = []
        while not errors.empty():
            got.append(errors.get())
        assert not [e for e in got if e.startswith("RunStore")], got
        study = optuna.load_study(study_name=STUDY_NAME, storage=storage_url(path))
        assert study.study_name == STUDY_NAME
