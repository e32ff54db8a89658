"""Watching the parameter file: inotify, polling as fallback, a stop event that ends it."""

import threading
import time

import pytest

from uav_depth.core.params import DEFAULT_PARAMS, save_params
from uav_depth.daemon.reload import FileWatcher


def wait_until(pred, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("inotify", [True, False], ids=["inotify", "poll"])
def test_atomic_replace_edit_and_removal_are_seen(tmp_path, inotify):
    path = tmp_path / "params.yaml"
    save_params(DEFAULT_PARAMS, path)
    seen = []
    stop = threading.Event()
    watcher = FileWatcher(path, seen.append, poll_s=0.1 if not inotify else 5.0, use_inotify=inotify).start(stop)
    try:
        time.sleep(0.2)
        assert watcher.mode == ("inotify" if inotify else "poll")
        def after(action, what):
            time.sleep(0.3)                 # let earlier events settle before counting
            n = len(seen)
            action()
            assert wait_until(lambda: len(seen) > n), f"{what} not seen"

        after(lambda: save_params(DEFAULT_PARAMS.replace(**{"sgbm.p1": 700}), path), "atomic replace")  # as the tuner
        after(lambda: open(path, "a").write("# edited\n"), "in-place edit")
        after(path.unlink, "removal")
        assert all(p == path for p in seen)
    finally:
        stop.set()
        assert watcher.join(2.0)


def test_stop_event_ends_the_watch_promptly(tmp_path):
    stop = threading.Event()
    watcher = FileWatcher(tmp_path / "p.yaml", lambda p: None, poll_s=30.0).start(stop)
    time.sleep(0.1)
    start = time.monotonic()
    stop.set()
    assert watcher.join(1.0) and time.monotonic() - start < 1.0


def test_a_failing_handler_does_not_end_the_watch(tmp_path):
    path = tmp_path / "p.yaml"
    calls = []

    def handler(p):
        calls.append(p)
        raise RuntimeError("boom")

    stop = threading.Event()
    watcher = FileWatcher(path, handler, poll_s=0.05, use_inotify=False).start(stop)
    try:
        path.write_text("a: 1\n")
        assert wait_until(lambda: len(calls) >= 1)
        time.sleep(0.2)
        n = len(calls)
        path.write_text("a: 22\n")
        assert wait_until(lambda: len(calls) > n)
    finally:
        stop.set()
        watcher.join(1.0)


def test_missing_directory_falls_back_to_polling(tmp_path):
    path = tmp_path / "later" / "params.yaml"
    seen = []
    stop = threading.Event()
    watcher = FileWatcher(path, seen.append, poll_s=0.05).start(stop)
    try:
        time.sleep(0.1)
        assert watcher.mode == "poll"
        save_params(DEFAULT_PARAMS, path)
        assert wait_until(lambda: seen == [path])
    finally:
        stop.set()
        watcher.join(1.0)


def test_a_change_before_the_watch_started_is_not_missed(tmp_path):
    from uav_depth.daemon.reload import file_signature

    path = tmp_path / "p.yaml"
    save_params(DEFAULT_PARAMS, path)
    read_at = file_signature(path)                    # the daemon read the file ...
    save_params(DEFAULT_PARAMS.replace(**{"sgbm.p1": 650}), path)   # ... the tuner replaced it ...
    seen = []
    stop = threading.Event()
    watcher = FileWatcher(path, seen.append, poll_s=0.05, since=read_at).start(stop)   # ... then the watch began
    try:
        assert wait_until(lambda: seen == [path])
    finally:
        stop.set()
        watcher.join(1.0)
