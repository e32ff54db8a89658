"""The one seam every evaluation goes through: serial, a local process pool, or Ray.

An executor is built with the frame sets and the fitness name; it hands them to
each worker once (pool initializer, Ray object store), then evaluates
:class:`~uav_depth.tuning.objective.Task` s. ``imap`` yields ``(index, Evaluation)``
as each finishes, so the caller can store every result at once; the caller puts
them back in order, which is why the number of workers never changes a result.

Every worker evaluates with OpenCV limited to one thread: the parallelism is
across candidates (SGBM's default mode is single-threaded anyway), and workers
must not oversubscribe the cores. The thread count changes no result: the
multi-threaded modes (sgbm_3way, hh4) split the image into a fixed number of
stripes (tests/core/test_disparity.py checks 1 vs 3 threads; 1, 2 and 4 gave
identical maps on the motorcycle pair and on synthetic 256x192..1280x720 frames).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Callable, Hashable, Iterator, Mapping, Protocol, Sequence

from uav_depth.core.errors import ConfigError, DependencyError
from uav_depth.core.ranging import RangingConfig

from uav_depth.tuning.frames import FrameSet
from uav_depth.tuning.objective import FLOWN_RANGING, Evaluation, Objective, Task

#: OpenCV threads per evaluating process (see the module docstring).
EVAL_THREADS = 1


#: What :meth:`Executor.stream` asks for whenever a worker is free: the next (handle, task), or None when there is
#: nothing to start now (asked again after the next task finishes).
Feed = Callable[[], "tuple[Hashable, Task] | None"]


class Executor(Protocol):
    workers: int
    kind: str

    def imap(self, tasks: Sequence[Task], stop: threading.Event | None = None) -> Iterator[tuple[int, Evaluation]]:
        """Evaluate ``tasks``; yield (index, evaluation) as each finishes. After ``stop``
        is set, start nothing new, yield what was already running, and return."""
        ...

    def stream(self, feed: Feed, stop: threading.Event | None = None) -> Iterator[tuple[Hashable, Evaluation]]:
        """Keep every worker busy with the tasks ``feed()`` hands out, no more than one a worker at a time, and
        yield (handle, evaluation) as each finishes; return when nothing runs and ``feed()`` has nothing. What
        to start next is decided when a worker is free, from what finished before (the search guide reads
        several candidates at once and stops each one at its first failed rule). After ``stop`` is set, start
        nothing new, yield what was already running, and return."""
        ...

    def close(self) -> None: ...


def imap_by_stream(executor: Executor, tasks: Sequence[Task],
                   stop: threading.Event | None = None) -> Iterator[tuple[int, Evaluation]]:
    """``imap`` as a :meth:`Executor.stream` of the tasks in order."""
    todo = iter(enumerate(tasks))
    return executor.stream(lambda: next(todo, None), stop)


def run_all(executor: Executor, tasks: Sequence[Task]) -> list[Evaluation]:
    """``map``: every task's evaluation, in task order."""
    out: list[Evaluation | None] = [None] * len(tasks)
    for i, ev in executor.imap(tasks):
        out[i] = ev
    return out  # type: ignore[return-value]


def _set_cv_threads(n: int) -> int:
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    return before


class SerialExecutor:
    """Evaluates in the calling process, one task after another."""

    kind = "serial"

    def __init__(self, framesets: Mapping[str, FrameSet], fitness: str, ranging: RangingConfig = FLOWN_RANGING):
        self.workers = 1
        self.objective = Objective(framesets, fitness, ranging)
        self._threads_before = _set_cv_threads(EVAL_THREADS)

    def imap(self, tasks, stop=None):
        return imap_by_stream(self, tasks, stop)

    def stream(self, feed, stop=None):
        while not (stop is not None and stop.is_set()):
            item = feed()
            if item is None:
                return
            yield item[0], self.objective(item[1])

    def close(self) -> None:
        _set_cv_threads(self._threads_before)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


_WORKER_OBJECTIVE: Objective | None = None


def _init_worker(framesets: Mapping[str, FrameSet], fitness: str, ranging: RangingConfig) -> None:
    """Pool initializer: the frames arrive here, once per worker process."""
    global _WORKER_OBJECTIVE
    # Ctrl-C in a terminal reaches the whole process group; the parent decides
    # what stops, a worker finishes its candidate so the result is kept.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _set_cv_threads(EVAL_THREADS)
    _WORKER_OBJECTIVE = Objective(framesets, fitness, ranging)


def _run_task(task: Task) -> Evaluation:
    assert _WORKER_OBJECTIVE is not None, "worker not initialised"
    return _WORKER_OBJECTIVE(task)


def _ready(pause_s: float) -> int:
    """A worker's process id once it is initialised (the pause spreads the calls over the workers)."""
    import time

    time.sleep(pause_s)
    return os.getpid()


class ProcessExecutor:
    """A local pool of ``workers`` processes (spawned: no fork of a threaded parent)."""

    kind = "process"

    def __init__(self, framesets: Mapping[str, FrameSet], fitness: str, workers: int,
                 ranging: RangingConfig = FLOWN_RANGING):
        import multiprocessing

        if workers < 1:
            raise ConfigError("--workers", "must be at least 1", workers)
        self.workers = workers
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_init_worker, initargs=(dict(framesets), fitness, ranging))

    def imap(self, tasks, stop=None):
        return imap_by_stream(self, tasks, stop)

    def stream(self, feed, stop=None):
        # One task a worker: a task queued behind the running ones could not be taken back when the caller
        # learns, from one that finishes, that it is not needed (ProcessPoolExecutor runs what it queued).
        running: dict = {}
        while True:
            while len(running) < self.workers and not (stop is not None and stop.is_set()):
                item = feed()
                if item is None:
                    break
                running[self.pool.submit(_run_task, item[1])] = item[0]
            if not running:
                return
            done, _ = wait(running, timeout=0.2, return_when=FIRST_COMPLETED)
            for f in done:
                yield running.pop(f), f.result()

    def warm(self, ready: Callable[[int, int], None] = lambda done, total: None, timeout_s: float = 120.0) -> None:
        """Start every worker now (each loads the frames once) and call ``ready(started, workers)`` as each
        is: the first evaluation then does not wait for a process to start, with nothing on the terminal."""
        seen: set[int] = set()
        deadline = time.monotonic() + timeout_s
        while len(seen) < self.workers and time.monotonic() < deadline:
            for f in [self.pool.submit(_ready, 0.05) for _ in range(self.workers)]:
                pid = f.result()
                if pid not in seen:
                    seen.add(pid)
                    ready(len(seen), self.workers)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _RayWorker:
    """A Ray actor holding the frames (from the object store, once) and the fitness."""

    def __init__(self, payload):
        framesets, fitness, ranging = payload
        _set_cv_threads(EVAL_THREADS)
        self.objective = Objective(framesets, fitness, ranging)

    def evaluate(self, task: Task) -> Evaluation:
        return self.objective(task)


class RayExecutor:
    """``workers`` Ray actors, each holding the frames; ``address`` None or "local" starts a local Ray.

    On a cluster (``address`` "auto" or "ray://host:10001") every node needs
    uav-depth installed; the frames travel through Ray's object store, so the
    nodes do not need the log directory.
    """

    kind = "ray"

    def __init__(self, framesets: Mapping[str, FrameSet], fitness: str, workers: int | None,
                 address: str | None = None, ranging: RangingConfig = FLOWN_RANGING):
        try:
            import ray
        except ImportError as exc:
            raise DependencyError("ray", "ray", "tuning with --ray-address") from exc
        self._ray = ray
        self._owns = not ray.is_initialized()
        if self._owns:
            local = address in (None, "", "local")
            ray.init(address=None if local else address, num_cpus=(workers or os.cpu_count()) if local else None,
                     include_dashboard=False, log_to_driver=False, configure_logging=False)
        n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.workers = n
        payload = ray.put((dict(framesets), fitness, ranging))
        actor = ray.remote(num_cpus=1)(_RayWorker)
        self.actors = [actor.remote(payload) for _ in range(n)]

    def imap(self, tasks, stop=None):
        return imap_by_stream(self, tasks, stop)

    def stream(self, feed, stop=None):
        ray = self._ray
        idle = list(self.actors)
        running: dict = {}
        while True:
            while idle and not (stop is not None and stop.is_set()):
                item = feed()
                if item is None:
                    break
                a = idle.pop()
                running[a.evaluate.remote(item[1])] = (item[0], a)
            if not running:
                return
            ready, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for ref in ready:
                handle, a = running.pop(ref)
                idle.append(a)
                yield handle, ray.get(ref)

    def close(self) -> None:
        for a in self.actors:
            self._ray.kill(a)
        if self._owns:
            self._ray.shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def make_executor(framesets: Mapping[str, FrameSet], fitness: str, workers: int | None = None,
                  ray_address: str | None = None, ranging: RangingConfig = FLOWN_RANGING) -> Executor:
    """Serial for one worker, a process pool for more, Ray when ``ray_address`` is given; every evaluation
    ranges with ``ranging`` (the ``ranging:`` section of the config that will fly).

    ``workers`` None: all cores of this machine (all CPUs of the Ray cluster).
    """
    if ray_address:
        return RayExecutor(framesets, fitness, workers, ray_address, ranging)
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ConfigError("--workers", "must be at least 1", n)
    return SerialExecutor(framesets, fitness, ranging) if n == 1 else ProcessExecutor(framesets, fitness, n, ranging)
