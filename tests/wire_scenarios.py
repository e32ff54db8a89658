"""Scenarios that put the real daemon process into each condition of the wire contract (see wire_rows.py).

Six daemon runs cover the nine conditions: a missing parameter file that then appears
(parameters unusable, measuring, shutting down), a replay whose first frame is unreadable
and whose frames then stop (starting, camera lost), a replay that ends (source
ended), and three steady scenes: a branch at 0.1 m (too close), nothing nearer than 6 m (nothing
confident) and ``ranging.max_age_ms: 1`` (stale).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from mavlink_peer import Receiver
from wire_rows import (GOOD, SCENE, Daemon, Window, arrival, beats_after, captured_at, config, expected, judge,
                       problems_of, stopped, window)

from uav_depth.core.fileio import atomic_write_text
from uav_depth.core.session import SessionWriter
from uav_depth.daemon.link.conditions import Condition
from uav_depth.sim.scene import Scene, SceneConfig

BRANCH_CM = round(SCENE["branch_distance_m"] * 100)
#: The gap replay's frame times (s): frame 0 unreadable (skipped), frames 1.8 s to 3.2 s, then one at 10.2 s. The 7 s
#: without a frame is a lost camera (frame timeout 3 s); the source is reopened and the replay starts again from
#: frame 0, so "camera back" comes with frame 1, 1.8 s later, and the frame at 10.2 s is never reached.
REPLAY_TIMES = [0.0] + [1.8 + 0.2 * i for i in range(8)] + [10.2]
REPLAY_FRAME_TIMEOUT_S = 3.0


@dataclass(frozen=True)
class Scenario:
    name: str
    conditions: tuple[Condition, ...]
    run: Callable[[Path], dict[Condition, Window]]


def params_missing_then_written(d: Path) -> dict[Condition, Window]:
    """No parameter file (parameters unusable), then the file (measuring), then SIGTERM (shutting down)."""
    rx = Receiver()
    params = d / "params.yaml"
    daemon = Daemon(d, config(rx.port, params))
    try:
        t_blind = arrival(rx, daemon, expected(Condition.PARAMS_UNUSABLE).texts[0])
        beats_after(rx, daemon, t_blind, 2)
        t_write = time.monotonic()
        atomic_write_text(params, GOOD)
        unusable = window(rx, t_blind, t_write)
        t_meas = arrival(rx, daemon, expected(Condition.MEASURING).texts[0], since=t_write)
        daemon.wait_for(lambda: len(rx.of("DISTANCE_SENSOR", t_meas)) >= 10 and len(rx.of("HEARTBEAT", t_meas)) >= 2,
                        "10 readings and 2 HEARTBEAT")
        measuring = window(rx, t_meas, time.monotonic())
        t_began, t_last, code = stopped(rx, daemon)
        shutting = window(rx, t_began, t_last)
    finally:
        daemon.kill()
        rx.close()
    cms = [m.current_distance for m in measuring.readings]
    measuring.notes.append(f"{min(cms)}..{max(cms)} cm (branch at {BRANCH_CM} cm)")
    shutting.problems += problems_of(daemon, code)
    return {Condition.PARAMS_UNUSABLE: unusable, Condition.MEASURING: measuring, Condition.SHUTTING_DOWN: shutting}


def write_replay(d: Path, times: list[float], unreadable_first: bool) -> Path:
    """A logged session of the 0.8 m scene, a frame at each of ``times`` (s); frame 0 skipped if unreadable."""
    cfg = SceneConfig(**SCENE)
    writer = SessionWriter(d / "log", cfg.calibration)
    scene = Scene(cfg)
    for i, t in enumerate(times):
        frame = scene.render(rng=np.random.default_rng(i))
        writer.write(i, frame.left, frame.right, meta={"time_s": t, "branch_distance_m": SCENE["branch_distance_m"]})
    if unreadable_first:
        writer.session.frames()[0].left_path.write_bytes(b"not a PNG")
    return d / "log"


def _replay(d: Path, rx: Receiver, times: list[float], unreadable_first: bool = False) -> Daemon:
    (d / "params.yaml").write_text(GOOD)
    cfg = config(rx.port, d / "params.yaml", source={"kind": "replay", "path": str(write_replay(d, times,
                                                                                                 unreadable_first))},
                 service={"frame_timeout_s": REPLAY_FRAME_TIMEOUT_S})
    return Daemon(d, cfg)


def replay_with_a_gap(d: Path) -> dict[Condition, Window]:
    """A replay: an unreadable first frame (starting), then a lost camera until the reopened replay's frame 1."""
    rx = Receiver()
    daemon = _replay(d, rx, REPLAY_TIMES, unreadable_first=True)
    try:
        t_lost = arrival(rx, daemon, expected(Condition.CAMERA_LOST).texts[0])
        t_back = arrival(rx, daemon, "uav-depth: camera back", since=t_lost)
        _, _, code = stopped(rx, daemon)
    finally:
        daemon.kill()
        rx.close()
    first = rx.timed("DISTANCE_SENSOR")[:1]            # until the first frame was captured, by its own stamp
    starting = window(rx, daemon.t_start, captured_at(*first[0]) if first else float("inf"))
    lost = window(rx, t_lost, t_back)
    lost.problems += problems_of(daemon, code)
    return {Condition.STARTING: starting, Condition.CAMERA_LOST: lost}


def replay_to_its_end(d: Path) -> dict[Condition, Window]:
    """A replay of 20 frames without loop: after the last, the source has ended and the daemon stops by itself.

    4 s of frames: the STATUSTEXT of the end is not held back by the one said when measuring began (one a
    second at most). The window from the end to "stopping" is shorter than a HEARTBEAT period: it may hold none.
    """
    rx = Receiver()
    daemon = _replay(d, rx, [0.2 * i for i in range(20)])
    try:
        code = daemon.exit_code()
        t_began, _, _ = stopped(rx, daemon)
    finally:
        daemon.kill()
        rx.close()
    t_last = max((t for t, _ in rx.timed("DISTANCE_SENSOR")), default=daemon.t_start)
    ended = window(rx, t_last, t_began - 1e-6, open_start=True)
    ended.notes.append(f"{t_began - t_last:.2f} s from the last reading to the shutdown")
    logged = "source delivered" in daemon.stderr()
    ended.problems += problems_of(daemon, code) + ([] if logged else ["no end of the source logged"])
    return {Condition.SOURCE_ENDED: ended}


def _settled(rx: Receiver, cond: Condition, t0: float) -> float | None:
    """The end of a steady window: 3 HEARTBEAT after ``t0``; more while the daemon was only stale (a loaded
    machine's stereo stage behind), up to 30."""
    beats = rx.timed("HEARTBEAT", t0)
    if len(beats) < 3:
        return None
    t1 = beats[-1][0]
    return t1 if judge(cond, window(rx, t0, t1)).ok or len(beats) >= 30 else None


def steady(cond: Condition, scene: dict | None = None, **sections) -> Callable[[Path], dict[Condition, Window]]:
    """A daemon that stays in ``cond``: its window runs from the condition's STATUSTEXT over 3 HEARTBEAT (more,
    up to 30, while a loaded machine keeps it stale)."""
    def run(d: Path) -> dict[Condition, Window]:
        rx = Receiver()
        (d / "params.yaml").write_text(GOOD)
        source = {"kind": "synthetic", "fps": 10, "scene": {**SCENE, **(scene or {})}}
        daemon = Daemon(d, config(rx.port, d / "params.yaml", source=source, **sections))
        try:
            t0 = arrival(rx, daemon, expected(cond).texts[0])
            if cond.sends:
                daemon.wait_for(lambda: len(rx.of("DISTANCE_SENSOR", t0)) >= 10, "10 readings")
            w = window(rx, t0, daemon.wait_for(lambda: _settled(rx, cond, t0), "3 HEARTBEAT in it"))
            _, _, code = stopped(rx, daemon)
        finally:
            daemon.kill()
            rx.close()
        early = [m for t, m in rx.timed("DISTANCE_SENSOR") if t < t0]
        if not cond.sends and early:
            w.problems.append(f"{len(early)} DISTANCE_SENSOR before it was said")
        w.problems += problems_of(daemon, code)
        return {cond: w}
    return run


SCENARIOS = (
    Scenario("params-missing-then-written", (Condition.PARAMS_UNUSABLE, Condition.MEASURING,
                                             Condition.SHUTTING_DOWN), params_missing_then_written),
    Scenario("replay-with-a-gap", (Condition.STARTING, Condition.CAMERA_LOST), replay_with_a_gap),
    Scenario("replay-to-its-end", (Condition.SOURCE_ENDED,), replay_to_its_end),
    Scenario("branch-at-0.1-m", (Condition.TOO_CLOSE,), steady(Condition.TOO_CLOSE, {"branch_distance_m": 0.1})),
    Scenario("nothing-nearer-than-6-m", (Condition.NOTHING_CONFIDENT,),
             steady(Condition.NOTHING_CONFIDENT, {"branch_distance_m": 6.0, "n_branches": 0})),
    Scenario("max-age-1-ms", (Condition.STALE,), steady(Condition.STALE, ranging={"max_age_ms": 1})),
)
SCENARIO_OF = {cond: s for s in SCENARIOS for cond in s.conditions}
