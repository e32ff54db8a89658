"""The tuner's safety sweep: synthetic branches from inside the minimum range out to the working distance,
rendered at the log's rig by the caller (``TuneRequest.safety``; the tuner renders nothing itself), on which every
candidate about to win and the chosen one are read as the daemon flies and compared with the base
(:class:`SafetyScreen`; docs/tuning.md, *The safety sweep*).

The sweep arrives as a session on disk (:class:`SweepFrames`: the caller renders it once per rig and keeps it);
the workers read it in small chunks, nearest branches first, straight from disk (a sweep at 1920x1080 is over a
gigabyte of pixels, so no process holds it whole), and a candidate that already reads more frames farther than
the base did is stopped there.
"""

from __future__ import annotations

import math
import statistics
import threading
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from uav_depth.core.errors import UavDepthError
from uav_depth.core.params import StereoParams, params_from_dict

from uav_depth.tuning.executor import Executor
from uav_depth.tuning.frames import DiskFrames, FrameData, FrameSet
from uav_depth.tuning.metrics import FARTHER_TOL_PCT, branch_signed, is_farther
from uav_depth.tuning.objective import Task
from uav_depth.tuning.robust import FartherCheck
from uav_depth.tuning.study import TuneInterrupted

#: The safety sweep's accuracy rule: in each scene variant (plain, varied, leafy), a candidate's median absolute
#: branch-distance error over the sweep frames it and the base both read may be at most SWEEP_MEDIAN_FACTOR x the
#: base's + SWEEP_MEDIAN_SLACK_PCT points (the slack: a base that reads a few frames almost exactly must not refuse
#: every change). Per variant, because gains on leafy frames must not hide a worse nominal case: on the
#: 330-frame sweep at 1280x720 the flight file reads the plain 3 cm branch 1.34 % off, four files tuned on leafy
#: scenes 2.2-3.1 %, and pooled over the variants one of them passed by 0.002 point and read the real pairs worse
#: (docs/tuning.md).
SWEEP_MEDIAN_FACTOR = 1.1
SWEEP_MEDIAN_SLACK_PCT = 0.25
#: How a candidate the safety sweep set aside is marked in the choice's rows (and so in the report).
UNSAFE = "unsafe: "
#: The order the scene variants are read in, each whole before the next: plain and varied first (a candidate that
#: ranges either less accurately than the base allows is stopped there, a third of the way in), then leafy (where
#: candidates read branches farther).
READ_ORDER = ("plain", "varied", "leafy")
#: Sweep frames per task: small enough that each worker reports every second or so at 1280x720 and that a
#: candidate stopped early has read little more than it had to, large enough that a task's start costs little.
CHUNK = 4


class SweepFrames:
    """The safety sweep at the log's rig, as the caller keeps it: a session in the log layout at ``path`` (each
    frame's meta holds its truth), its frame ids and keys in order (``plain-s10-0.40m``: the scene variant, seed
    and the branch's distance), and ``render``, which renders what is not on disk yet and returns each frame's
    truth (the nearest significant object's distance, m). Nothing is rendered until a candidate needs the sweep:
    a tune whose choice finds nothing better than the base never pays for it."""

    def __init__(self, path: str, frame_ids: Sequence[str], keys: Sequence[str],
                 render: Callable[[], Sequence[float]], prefix: str = "sweep"):
        self.path, self.frame_ids, self.keys = str(path), tuple(frame_ids), tuple(keys)
        self._render = render
        self.prefix = prefix      # the executor's frame sets of it: prefix0, prefix1 ... (framesets)
        self._truths: tuple[float, ...] | None = None

    def __len__(self) -> int:
        return len(self.frame_ids)

    @property
    def truths(self) -> tuple[float, ...]:
        """Each frame's truth, m; the first call renders what is missing."""
        if self._truths is None:
            self._truths = tuple(float(t) for t in self._render())
        return self._truths

    @property
    def variants(self) -> list[str]:
        """The scene variants of the sweep's frames, in the order they are read (READ_ORDER, then any other)."""
        return sorted({variant_of(k) for k in self.keys}, key=lambda v: (READ_ORDER.index(v)
                                                                        if v in READ_ORDER else len(READ_ORDER), v))

    def chunks(self) -> list[list[int]]:
        """Frame indices in tasks of CHUNK: one scene variant after the other (:attr:`variants`; no chunk holds
        two, so a variant's frames are all read at a chunk boundary and its median can be judged there), nearest
        branch first within each (where candidates go wrong: inside and just outside the minimum range), so that
        a failing candidate is stopped early."""
        out: list[list[int]] = []
        for v in self.variants:
            order = sorted((i for i in range(len(self)) if variant_of(self.keys[i]) == v),
                           key=lambda i: (_nominal_m(self.keys[i]), i))
            out += [order[i:i + CHUNK] for i in range(0, len(order), CHUNK)]
        return out

    def framesets(self) -> dict[str, DiskFrames]:
        """The executor's frame sets of the sweep, one per chunk of :meth:`chunks` (``sweep0``, ``sweep1`` ...
        with the default prefix): paths only, read by the workers when a candidate is read."""
        return {self._name(j): DiskFrames(self._name(j), [(self.path, self.frame_ids[i]) for i in idx])
                for j, idx in enumerate(self.chunks())}

    def task(self, params: Mapping[str, Any], chunk: int) -> Task:
        """The task that reads ``params`` as the daemon flies on chunk ``chunk`` of :meth:`framesets`."""
        return Task(dict(params), self._name(chunk), reading=True)

    def _name(self, chunk: int) -> str:
        return f"{self.prefix}{chunk}"


def _nominal_m(key: str) -> float:
    """The branch distance a sweep key names (``leafy-s10-0.40m``: 0.40), inf when it names none."""
    try:
        return float(key.rsplit("-", 1)[-1].rstrip("m"))
    except ValueError:
        return float("inf")


def rig(frame: FrameData) -> tuple:
    return frame.left.shape[:2], frame.focal_px, frame.baseline_m


def rig_sample(train: FrameSet) -> FrameData | None:
    """The first calibrated training frame of the rig (image size, focal length, baseline) most of them share:
    the safety sweep is rendered at its rig. None without a calibrated frame."""
    calibrated = [f for f in train.frames if f.focal_px and f.baseline_m]
    if not calibrated:
        return None
    common = Counter(rig(f) for f in calibrated).most_common(1)[0][0]
    return next(f for f in calibrated if rig(f) == common)


def variant_of(key: str) -> str:
    """The scene variant of a sweep frame, from its key (``plain-s10-0.40m``: plain)."""
    return key.rsplit("/", 1)[-1].split("-", 1)[0]


@dataclass(frozen=True)
class Reading:
    """What one parameter set read on the sweep: distances in m per frame (NaN: no distance, or not read),
    how many frames were read (all of them unless stopped early), the scene variants read whole, the reason when
    it could not be read."""

    distances: tuple[float, ...]
    read: int
    whole: tuple[str, ...] = ()
    failed: str | None = None


class SafetyScreen:
    """The safety sweep, read through ``executor`` (whose frame sets include ``sweep.framesets()``).

    A candidate fails it when it reads more sweep frames farther than the truth (by more than FARTHER_TOL_PCT)
    than the base, or when in some scene variant its median absolute error over the frames both read exceeds
    SWEEP_MEDIAN_FACTOR x the base's + SWEEP_MEDIAN_SLACK_PCT: synthetic scenes judge safety and the nominal case
    here, the log's own frames judge the rest. :meth:`reject` is the choice's screen (choice.select): a
    candidate about to win that fails is set aside and the next one tried. :meth:`check` is the gate's verdict on
    the chosen parameters. Every parameter set is read once (the base first, once for every fold and the gate).
    ``progress(what, done, total)``: frames read so far; ``stop``: the tune's stop event (Ctrl-C)."""

    def __init__(self, sweep: SweepFrames | None, base: StereoParams, executor: Executor | None = None,
                 progress: Callable[[str, int, int], None] = lambda what, done, total: None,
                 stop: threading.Event | None = None, phase: Callable[[str], None] = lambda text: None):
        self.sweep, self.base, self.executor = sweep, base, executor
        self.progress, self.stop, self.phase = progress, stop, phase
        self._chunks = sweep.chunks() if sweep is not None else []
        self._readings: dict[StereoParams, Reading] = {}
        self._labels = 0

    @property
    def active(self) -> bool:
        return self.sweep is not None and self.executor is not None

    def reading(self, params: StereoParams, limit: int | None = None, base: Reading | None = None) -> Reading:
        """``params`` read on the sweep, once; with ``limit``, stopped as soon as more than ``limit`` frames read
        farther than the truth, and with ``base`` (its reading) as soon as a scene variant read whole fails the
        accuracy rule against it (either way the verdict is then known: it fails)."""
        known = self._readings.get(params)
        if known is not None and (known.read == len(self.sweep) or known.failed or limit is not None):
            return known
        if not self._readings:
            self.phase(f"the safety sweep: the base and each candidate about to win, as the daemon flies them, on "
                       f"{len(self.sweep)} synthetic branches from inside the minimum range out to 3 m")
        label = "the base" if params == self.base else f"candidate {self._next_label()}"
        reading = self._read(params, label, limit, base)
        self._readings[params] = reading
        if self.stop is not None and self.stop.is_set():
            raise TuneInterrupted("interrupted in the safety sweep; run the same command with --resume to "
                                  "continue (every search result is kept)")
        return reading

    def _next_label(self) -> int:
        self._labels += 1
        return self._labels

    def _read(self, params: StereoParams, label: str, limit: int | None, base: Reading | None) -> Reading:
        sweep, n = self.sweep, len(self.sweep)
        truths = sweep.truths       # rendered here when no candidate needed the sweep before
        out = [math.nan] * n
        tasks = [sweep.task(params.to_dict(), j) for j in range(len(self._chunks))]
        left = Counter(variant_of(sweep.keys[idx[0]]) for idx in self._chunks)   # chunks of each variant to read
        halt = threading.Event()
        read = farther = 0
        whole: list[str] = []
        for j, ev in self.executor.imap(tasks, halt):
            if not ev.ok:
                halt.set()
                return Reading(tuple(out), read, tuple(whole), ev.reason)
            for i, d in zip(self._chunks[j], ev.per_frame):
                out[i] = d
                farther += read_farther(d, truths[i])
            read += len(self._chunks[j])
            variant = variant_of(sweep.keys[self._chunks[j][0]])
            left[variant] -= 1
            if not left[variant]:
                whole.append(variant)
            self.progress(f"safety sweep: {label}, frames read", read, n)
            less_accurate = base is not None and not left[variant] and median_fails(
                variant_medians(errors_both_read(sweep.keys, truths, base.distances, out)).get(variant))
            if ((limit is not None and farther > limit) or less_accurate
                    or (self.stop is not None and self.stop.is_set())):
                halt.set()
        return Reading(tuple(out), read, tuple(whole))

    def _verdict(self, params: StereoParams, rejecting: bool) -> FartherCheck:
        sweep = self.sweep
        base = self.reading(self.base)
        if base.failed:
            raise UavDepthError(f"the base parameters cannot be read on the safety sweep: {base.failed}")
        nb = farther_count(base.distances, sweep.truths)
        tuned = self.reading(params, *((nb, base) if rejecting else ()))
        who = "reads" if rejecting else "the tuned parameters read"
        if tuned.failed:
            return FartherCheck(nb, 0, len(sweep), f"{who} no distance on the safety sweep: {tuned.failed}")
        nt = farther_count(tuned.distances, sweep.truths)
        reasons = []
        if nt > nb:
            first = f"the first {tuned.read} of " if tuned.read < len(sweep) else ""
            reasons.append(f"{who} {nt} of {first}the {len(sweep)} safety-sweep frame(s) farther than the truth by "
                           f"more than {FARTHER_TOL_PCT:g} %, the base {nb}")
        both = errors_both_read(sweep.keys, sweep.truths, base.distances, tuned.distances)
        pooled = [e for es in both.values() for e in es]
        mb, mt = ((statistics.median(e[i] for e in pooled) if pooled else None) for i in (0, 1))
        for variant, (n, vb, vt) in variant_medians(both).items():
            if variant in tuned.whole and median_fails((n, vb, vt)):
                    reasons.append(f"{who} the {n} {variant} safety-sweep frame(s) both read with a median "
                                   f"absolute error of {vt:.2f} %, above {SWEEP_MEDIAN_FACTOR:g} x the base's "
                                   f"{vb:.2f} % + {SWEEP_MEDIAN_SLACK_PCT:g}")
        return FartherCheck(nb, nt, len(sweep), "; ".join(reasons) or None, base_median=mb, tuned_median=mt)

    def reject(self, params_dict: dict[str, Any]) -> str | None:
        """Why a candidate may not win (it fails the sweep), or None."""
        why = self._verdict(params_from_dict(params_dict), rejecting=True).reason
        return None if why is None else UNSAFE + why

    def check(self, chosen: StereoParams) -> FartherCheck | None:
        """The base's and the chosen parameters' figures on the sweep and the gate's refusal when the chosen fails
        it; None when inactive or when the base is kept (nothing to check)."""
        if not self.active or chosen == self.base:
            return None
        return self._verdict(chosen, rejecting=False)


def median_fails(medians: tuple[int, float, float] | None) -> bool:
    """Whether a scene variant's (frames both read, base's median, candidate's median) of :func:`variant_medians`
    fails the accuracy rule (None: no frame both read, nothing to fail)."""
    return medians is not None and medians[2] > median_limit_pct(medians[1])


def read_farther(distance_m: float, truth_m: float) -> bool:
    """Whether a sweep frame was read farther than its truth by more than FARTHER_TOL_PCT (NaN: nothing read)."""
    return is_farther(None if math.isnan(distance_m) else distance_m, truth_m)


def farther_count(distances: Sequence[float], truths: Sequence[float]) -> int:
    """How many sweep frames were read farther than their truth (:func:`read_farther`)."""
    return sum(read_farther(d, t) for d, t in zip(distances, truths))


def errors_both_read(keys: Sequence[str], truths: Sequence[float], base: Sequence[float],
                     tuned: Sequence[float]) -> dict[str, list[tuple[float, float]]]:
    """Per scene variant (from the frame keys): (base, tuned) absolute error % on the frames both read (distances
    in m, NaN where none was read)."""
    both: dict[str, list[tuple[float, float]]] = {}
    for key, b, c, t in zip(keys, base, tuned, truths):
        if math.isfinite(t) and t > 0 and math.isfinite(b) and math.isfinite(c):
            both.setdefault(variant_of(key), []).append((abs(branch_signed(b, t)), abs(branch_signed(c, t))))
    return both


def variant_medians(both: dict[str, list[tuple[float, float]]]) -> dict[str, tuple[int, float, float]]:
    """Per scene variant of :func:`errors_both_read`: (frames both read, the base's and the candidate's median
    absolute error %)."""
    return {v: (len(es), statistics.median(e[0] for e in es), statistics.median(e[1] for e in es))
            for v, es in both.items()}


def median_limit_pct(base_median_pct: float) -> float:
    """The sweep's accuracy rule: the most a candidate's median absolute error in a scene variant may be, given the
    base's over the same frames (SWEEP_MEDIAN_FACTOR, SWEEP_MEDIAN_SLACK_PCT)."""
    return SWEEP_MEDIAN_FACTOR * base_median_pct + SWEEP_MEDIAN_SLACK_PCT
