"""Which frames each step of a tune sees: the search trains on one part, the choice is made on a second
(validation), and the gate and the report judge on a third (test) that nothing in the choice saw.

The test frames are set aside first (``--test``), then the rest is split into training and validation frames
(``--holdout``, or k folds by session: ``--folds``, :mod:`.robust`). ``auto`` for each:

- ``--test auto``: with two or more sessions, the last quarter of them (at least one, in name order); a single
  session holds out its last :data:`TEST_FRACTION` of frames, one contiguous block; none when ``--holdout none``.
- ``--holdout auto``: of the sessions left, k folds when there are 2..8 (:func:`~uav_depth.tuning.robust.auto_folds`),
  else the last third of them; a single session's last :data:`VALIDATION_FRACTION` of the frames left.

Other values (both options): ``none``; a fraction 0 < f < 1 (the last ceil(f * n) frames of each session, one
block, at least one frame kept); a directory (a session or a directory of sessions); or a comma list of
session names, ``session/frame`` keys or frame ids.

Frames of one session are one flight: a block of its last seconds is not independent of the seconds before,
so a split inside a session is named in :attr:`Split.notes` and the report warns of it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.session import FrameRecord, find_sessions, iter_frames

from uav_depth.tuning.frames import FrameData, FrameSet, load_frame
from uav_depth.tuning.robust import parse_folds

#: Share of a single session's frames ``--test auto`` holds out (its last block), and of the sessions of a log.
TEST_FRACTION = 0.2
TEST_SESSIONS = 1 / 4
#: Share of a single session's remaining frames ``--holdout auto`` holds out for the choice, and of the sessions.
VALIDATION_FRACTION = 0.3
VALIDATION_SESSIONS = 1 / 3
#: The frame set names: fold j trains on TRAIN + j and chooses on VALIDATION + j (fold 0: no suffix).
TRAIN, VALIDATION, TEST = "train", "validation", "test"


def set_names(k: int) -> list[tuple[str, str]]:
    """The executor's (train, validation) frame-set names of each fold: fold 0 is the plain pair."""
    return [(TRAIN, VALIDATION)] + [(f"{TRAIN}{j}", f"{VALIDATION}{j}") for j in range(1, k)]


@dataclass(frozen=True)
class Split:
    """The frames of one tune by role. ``folds``: (train, validation) per fold (one for a single split);
    ``test``: what only the gate and the report see; ``notes``: what the report must say about them (a split
    inside one session, no test frame)."""

    folds: tuple[tuple[FrameSet, FrameSet], ...]
    test: FrameSet
    notes: tuple[str, ...] = ()

    @property
    def k(self) -> int:
        return len(self.folds)

    def framesets(self) -> dict[str, FrameSet]:
        """Every frame set by its executor name (:func:`set_names`, and :data:`TEST`)."""
        out = {TEST: self.test}
        for (tn, vn), (tr, va) in zip(set_names(self.k), self.folds):
            out[tn], out[vn] = tr, va
        return out

    def roles(self) -> dict[str, list[str]]:
        """Frame keys by role: the search's (every fold's), the choice's, the gate's."""
        train = sorted({f.key for tr, _ in self.folds for f in tr.frames})
        validation = sorted({f.key for _, va in self.folds for f in va.frames})
        return {TRAIN: train, VALIDATION: validation, TEST: self.test.keys}


def _is_dir(text: str) -> bool:
    """Whether ``text`` names a directory; False for text no path can be (a list of names longer than the
    system's name limit raises OSError from stat, which is not a directory either)."""
    try:
        return Path(text).is_dir()
    except (OSError, ValueError):
        return False


def _by_session(records: Sequence[FrameRecord]) -> dict[Path, list[FrameRecord]]:
    out: dict[Path, list[FrameRecord]] = {}
    for r in records:
        out.setdefault(r.session.path.resolve(), []).append(r)
    return out


def hold_out(records: Sequence[FrameRecord], spec: str | None, option: str, fraction: float,
             sessions_share: float = VALIDATION_SESSIONS) -> tuple[list[FrameRecord], list[FrameRecord]]:
    """(kept, held out) of ``records`` by one option's rule (module docstring); ``fraction``: auto's share of a
    single session's frames, ``sessions_share`` of a log's sessions. ``option`` names the option in errors."""
    records = list(records)
    if not spec or spec == "none" or not records:
        return records, []
    sessions = _by_session(records)
    if spec == "auto":
        if len(sessions) >= 2:
            held_paths = set(list(sessions)[len(sessions) - math.ceil(len(sessions) * sessions_share):])
            held = [r for r in records if r.session.path.resolve() in held_paths]
            return [r for r in records if r not in held], held
        spec = str(fraction)
    if _is_dir(spec):
        held_keys = {(r.session.path.resolve(), r.frame_id) for r in iter_frames(spec)}
        held = [r for r in records if (r.session.path.resolve(), r.frame_id) in held_keys]
        return [r for r in records if r not in held], held
    try:
        share = float(spec)
    except ValueError:
        return _named(records, spec, option)
    if not 0 < share < 1:
        raise ConfigError(option, "must be a fraction between 0 and 1, a directory or a list of names", spec)
    kept, held = [], []
    for frames in sessions.values():
        n = min(math.ceil(share * len(frames)), len(frames) - 1)
        kept += frames[:len(frames) - n]
        held += frames[len(frames) - n:]
    return kept, held


def _named(records: list[FrameRecord], spec: str, option: str) -> tuple[list[FrameRecord], list[FrameRecord]]:
    names = {n.strip() for n in spec.split(",") if n.strip()}
    matched: set[str] = set()
    held = []
    for r in records:
        hit = {r.session.path.name, r.key, r.frame_id} & names
        if hit:
            held.append(r)
            matched |= hit
    unknown = names - matched
    if unknown:
        raise ConfigError(option, "must name sessions, session/frame keys or frame ids of the log (and not "
                          "frames another option already holds out)", ", ".join(sorted(unknown)))
    return [r for r in records if r not in held], held


def _inside(held: Sequence[FrameRecord], kept: Sequence[FrameRecord]) -> list[str]:
    """The sessions that lend frames to both ``held`` and ``kept`` (a split inside one flight)."""
    shared = set(_by_session(held)) & set(_by_session(kept))
    return sorted(p.name for p in shared)


def plan(logdir: str | os.PathLike[str], test: str | None, holdout: str | None, folds: str | None,
         needs: Iterable[str]) -> Split:
    """Load ``logdir``'s frames (each once) and split them by role (module docstring); only frames with what
    the fitness ``needs`` (reference, branch) are kept. Raises ConfigError / FileFormatError on bad input."""
    needs = tuple(needs)
    records = list(iter_frames(logdir))
    if not records:
        raise FileFormatError(f"{logdir}: no frames found")
    test_spec = None if (test == "auto" and holdout in (None, "", "none")) else test
    rest, test_r = hold_out(records, test_spec, "--test", TEST_FRACTION, TEST_SESSIONS)
    cache: dict[tuple[Path, str], FrameData] = {}

    def load(rs: Sequence[FrameRecord], name: str) -> FrameSet:
        frames = [cache.setdefault((r.session.path.resolve(), r.frame_id), load_frame(r)) for r in rs]
        return FrameSet(name, tuple(frames)).filter(needs)

    notes = []
    if test_r and _inside(test_r, rest):
        notes.append(f"the test frames are the last block of session(s) {', '.join(_inside(test_r, rest))}, "
                     "the same flight as the training frames: correlated, so the test figure is optimistic")
    k = parse_folds(folds, len(_by_session(rest)), holdout)
    if k > 1:
        pairs = _fold_records(rest, k)
    else:
        train_r, valid_r = hold_out(rest, holdout, "--holdout", VALIDATION_FRACTION)
        pairs = [(train_r, valid_r)]
        if valid_r and _inside(valid_r, train_r):
            notes.append(f"the validation frames are the last block of session(s) "
                         f"{', '.join(_inside(valid_r, train_r))}, the same flight as the training frames")
    split_folds = tuple((load(tr, TRAIN), load(va, VALIDATION)) for tr, va in pairs)
    for j, (tr, _) in enumerate(split_folds):
        if not len(tr):
            raise FileFormatError(_no_training(logdir, needs, j, k))
    test_set = load(test_r, TEST)
    if not len(test_set):
        notes.append("no test frame: the gate judges on the frames the choice was made on, which are not "
                     "independent of it")
    return Split(split_folds, test_set, tuple(notes))


def _fold_records(records: Sequence[FrameRecord], k: int) -> list[tuple[list[FrameRecord], list[FrameRecord]]]:
    """k (train, validation) splits by session: fold j holds out the sessions j, j+k, j+2k ... (name order)."""
    groups = list(_by_session(records).values())
    return [([r for i, g in enumerate(groups) if i % k != j for r in g],
             [r for i, g in enumerate(groups) if i % k == j for r in g]) for j in range(k)]


def _no_training(logdir, needs: tuple[str, ...], fold: int, k: int) -> str:
    what = " and ".join(needs) or "frames"
    where = f" in fold {fold + 1} of {k}" if k > 1 else " (after --test and --holdout)"
    hint = ""
    if "reference" in needs:
        hint = ("; give the frames a reference disparity (uav-depth reference import LOGDIR --from DIR, or "
                "uav-depth reference onnx), or tune without one: --metric selfsup")
    elif "branch" in needs:
        hint = "; the branch metric needs each frame's branch_distance_m (synthetic sessions carry it)"
    return f"{logdir}: no training frame with {what}{where}{hint}"


def load_split(logdir: str | os.PathLike[str], holdout: str | None, needs: Iterable[str]) -> tuple[FrameSet, FrameSet]:
    """(train, held out) of ``logdir`` by one ``--holdout`` rule, no test split: for benchmarks and tools that
    judge elsewhere."""
    needs = tuple(needs)
    train_r, held_r = hold_out(list(iter_frames(logdir)), holdout, "--holdout", VALIDATION_FRACTION)
    train = FrameSet(TRAIN, tuple(load_frame(r) for r in train_r)).filter(needs)
    if not len(train):
        raise FileFormatError(_no_training(logdir, needs, 0, 1))
    return train, FrameSet("holdout", tuple(load_frame(r) for r in held_r)).filter(needs)


def load_folds(logdir: str | os.PathLike[str], k: int, needs: Iterable[str]) -> list[tuple[FrameSet, FrameSet]]:
    """k (train, held-out) splits of every session of ``logdir``, no test split (benchmarks)."""
    needs = tuple(needs)
    if k < 2 or len(find_sessions(logdir)) < k:
        raise ConfigError("--folds", f"needs at least as many sessions as folds "
                          f"({len(find_sessions(logdir))} sessions)", k)
    out = []
    for tr, va in _fold_records(list(iter_frames(logdir)), k):
        out.append((FrameSet(TRAIN, tuple(map(load_frame, tr))).filter(needs),
                    FrameSet("holdout", tuple(map(load_frame, va))).filter(needs)))
    return out


__all__ = ["Split", "hold_out", "load_folds", "load_split", "plan", "set_names"]
