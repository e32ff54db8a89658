"""The readings the real-SITL test judges at 3-4 m, checked in process where CI runs (no ArduPilot).

tests/cli/test_sitl_ardupilot.py needs the ArduCopter binary, so CI skips it, and its Loiter 1 m/s reading lag
can break unseen (issue 47): the first readings of an approach, those the autopilot has while still at speed,
are of a branch beyond the stated range (3.49 m for this camera), which the fine pass's near tail can read
inside it, 9-55 cm nearer than it is (docs/measurements/ranging-precision-at-body.md). This flies the same scene without an autopilot: deploy/examples/sitl.yaml
(640x360, its flight file, its ranging, the scene ``uav-depth sitl`` renders), hovering with an autopilot's
jitter inside the stated range (3.0-3.45 m) and beyond it (3.56-3.68 m), and approaching at 1 m/s (that test's
Loiter speed) from 4.5 to 3.0 m. Each frame goes through the daemon's own pipeline, ranging, outlier gate and
DISTANCE_SENSOR encoding.

Checked: every reading sent lies within two of the sigmas it is sent with (plus the wire's whole centimetre)
of the ray-cast truth; a branch beyond the stated range is not sent as a distance (the range ends where the
covariance the wire carries ends, docs/wire.md); and the approach's reading lag is within the real test's
bounds (tests/sitl_bounds.py). Time is the frames' own stamps at the source's rate and the link's ticks at its
rate, never the wall clock; a reading counts as sent at its frame's capture, so the lag's lower bound is
stricter here than on the real autopilot, where the vehicle flies on while the frame is processed.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from sitl_bounds import reading_lag_bounds
from uav_depth.cli.sources import SOURCES
from uav_depth.core.params import load_params
from uav_depth.core.ranging import OutlierGate, resolve_roi
from uav_depth.daemon.config import load_run_config
from uav_depth.daemon.estimate import Estimate
from uav_depth.daemon.link.contract import distance_report
from uav_depth.daemon.stage import build_stage
from uav_depth.sim.scene import Pose, Scene
from uav_depth.sim.sitl import rot_x, rot_y

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy/examples/sitl.yaml"
#: Hovers inside the stated range (m from the branch surface), and beyond it by more than the 2 % the
#: benchmarks allow a reading.
INSIDE_M = (3.0, 3.3, 3.45)
BEYOND_M = (3.56, 3.6, 3.68)
HOVER_FRAMES = 8
#: tests/cli/test_sitl_ardupilot.py's Loiter speed, through the distances at which it is at speed there.
APPROACH_MPS, APPROACH_FROM_M, APPROACH_TO_M = 1.0, 4.5, 3.0
#: An autopilot's hover: roll and pitch (rad) and sideways position (m), 1 sigma (bench/sitl_hover.py's).
JITTER = (0.01, 0.01, 0.02)
#: DISTANCE_SENSOR carries whole centimetres.
WIRE_M = 0.01


@dataclass(frozen=True)
class Reading:
    """A distance the link sends for one frame (m), the frame's capture stamp (s) and its ray-cast truth."""

    t: float
    truth_m: float
    sent_m: float
    sigma_m: float

    def outside_two_sigma(self) -> bool:
        return abs(self.sent_m - self.truth_m) > 2.0 * self.sigma_m + WIRE_M


@pytest.fixture(scope="module")
def daemon():
    """The laptop example as the daemon builds it: its config, stage (pipeline + ranger) and ranging ROI."""
    config = load_run_config(EXAMPLE, sources=SOURCES)
    scene = config.source.scene
    roi = resolve_roi(config.ranging.roi, scene.width, scene.height)
    stage = build_stage(load_params(config.params_file), str(config.params_file), config.ranging,
                        scene.calibration, roi)
    return config, stage, roi


def fly(daemon, distance_at, frames: int, noise_seed: int) -> list[tuple[float, Reading | None]]:
    """Frames at the source's rate, the rig ``distance_at(t)`` m from the example scene's branch.

    Each frame as the stereo thread processes it (``daemon/stereo.py``): ranging, the outlier gate (a too-close
    frame booked, a jump away held back until confirmed), the estimate. Returned: each update of the estimate
    the link sends from, (capture stamp, the distance it sends or None for none). ``noise_seed`` draws the
    jitter and the sensor noise.
    """
    config, stage, roi = daemon
    start_m = distance_at(0.0)
    scene = Scene(replace(config.source.scene, branch_distance_m=start_m))
    lim = stage.ranger.limits
    max_age_s = config.ranging.max_age_ms / 1000.0
    gate = OutlierGate(config.ranging.max_jump_rel, config.ranging.confirm_frames)
    updates: list[tuple[float, Reading | None]] = []
    for i in range(frames):
        t = i / config.source.fps
        rng = np.random.default_rng([noise_seed, i, round(100 * start_m)])
        j = rng.normal(0.0, JITTER)
        frame = scene.render(Pose(rot_x(j[0]) @ rot_y(j[1]), np.array([j[2], 0.0, start_m - distance_at(t)])), rng)
        truth = frame.nearest_branch_distance(roi)
        m = gate.near(stage.ranger.measure(stage.pipeline.run(frame.left, frame.right)), lim.min_distance_m, t)
        if m.valid and not gate.accept(m.distance_m, t):
            continue                  # held back: the previous estimate stays until it ages out
        r = distance_report(Estimate(m, lim, t, t, i, stage.hash, truth, too_close=m.too_close), lim, t, max_age_s)
        updates.append((t, Reading(t, truth, r.current_distance / 100.0, math.sqrt(r.covariance) / 100.0)
                        if r.valid else None))
    return updates


def sent(updates) -> list[Reading]:
    return [r for _, r in updates if r is not None]


@pytest.fixture(scope="module")
def hovers(daemon):
    return {d: sent(fly(daemon, lambda t, d=d: d, HOVER_FRAMES, noise_seed=1)) for d in INSIDE_M + BEYOND_M}


@pytest.mark.timeout(240)
def test_hovers_inside_the_stated_range_read_within_two_sigma(hovers):
    for d in INSIDE_M[:2]:
        assert len(hovers[d]) >= HOVER_FRAMES // 2, (d, hovers[d])     # measured: not met by silence
    for d in INSIDE_M:
        assert not [r for r in hovers[d] if r.outside_two_sigma()], (d, hovers[d])


@pytest.mark.timeout(240)
def test_a_branch_beyond_the_stated_range_is_not_sent_as_a_distance(daemon, hovers):
    """Judged at the object's median depth, the fine pass's near tail no longer brings a branch beyond the range
    inside it (a whole-pixel false match, whose median is on the false match too, still can:
    docs/measurements/ranging-precision-at-body.md)."""
    stated_m = daemon[1].ranger.limits.stated_max_m
    assert BEYOND_M[0] > 1.02 * stated_m
    for d in BEYOND_M:
        assert hovers[d] == [], f"a branch {d} m away, beyond the stated {stated_m:.3f} m, sent: {hovers[d]}"


@pytest.mark.timeout(240)
def test_an_approach_at_1_mps_reads_within_two_sigma_and_the_real_tests_lag(daemon):
    """The reading lag as tests/cli/test_sitl_ardupilot.py takes it: at each tick of the link (its rate), the
    newest estimate, if it is a distance no older than ``ranging.max_age_ms``, against the geometry then."""
    config = daemon[0]
    frames = int((APPROACH_FROM_M - APPROACH_TO_M) / APPROACH_MPS * config.source.fps) + 1
    updates = fly(daemon, lambda t: APPROACH_FROM_M - APPROACH_MPS * t, frames, noise_seed=2)
    readings = sent(updates)
    assert len(readings) >= 5, readings
    assert not [r for r in readings if r.outside_two_sigma()], readings
    max_age_s = config.ranging.max_age_ms / 1000.0
    lags = []
    for k in range(int(updates[-1][0] * config.mavlink.rate_hz) + 1):
        tick = k / config.mavlink.rate_hz
        _, r = max((u for u in updates if u[0] <= tick), key=lambda u: u[0])
        if r is not None and tick - r.t <= max_age_s:
            lags.append(r.sent_m - (r.truth_m - APPROACH_MPS * (tick - r.t)))
    lo, hi = reading_lag_bounds(APPROACH_MPS, max_age_s)
    lag = statistics.median(lags)
    assert lo <= lag <= hi, f"reading lag median {lag:+.3f} m outside [{lo:+.3f}, {hi:+.3f}] m: {readings}"
