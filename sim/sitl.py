"""SITL: render the synthetic tree scene from a simulated vehicle's pose.

The autopilot (ArduPilot or PX4 SITL, or the test vehicle) streams LOCAL_POSITION_NED
and ATTITUDE; :class:`PoseTracker` keeps the latest of each and turns them into the
pose of the virtual stereo rig in the scene's world frame, which the synthetic source
renders. Frames involved:

- NED: the autopilot's local frame (x north, y east, z down, m), LOCAL_POSITION_NED.
- body FRD: x forward, y right, z down. ATTITUDE's roll, pitch, yaw (rad) rotate NED
  into body in Z-Y-X order: R_ned_body = Rz(yaw) Ry(pitch) Rx(roll).
- camera: x right, y down, z forward (OpenCV), fixed on the body, looking forward,
  tilted up by ``camera_pitch_deg``, its (left) centre at ``camera_offset_m`` (body FRD).
- scene world (:mod:`uav_depth.sim.scene`): the camera frame of the *anchor*, a
  level pose facing the tree from ``scene.branch_distance_m`` away, so the target
  branch is straight ahead of it at that distance. Without ``tree_ned_m`` the anchor
  is the rig's start pose (levelled): the tree stands that far in front of the start.

A :class:`~uav_depth.sim.scene.Pose` has the camera axes as rotation columns and
the camera centre as position, both in world coordinates.

What was rendered from which pose, beside the ground truth, is :mod:`uav_depth.sim.truthlog`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from uav_depth.core.errors import ConfigError, SourceError
from uav_depth.sim.scene import Pose

log = logging.getLogger("uav_depth.sitl")

#: Camera axes (columns: x right, y down, z forward) in body FRD coordinates, camera level.
R_BODY_CAMERA = np.array([[0.0, 0.0, 1.0],
                          [1.0, 0.0, 0.0],
                          [0.0, 1.0, 0.0]])

#: MAVLink message ids requested with MAV_CMD_SET_MESSAGE_INTERVAL.
MSG_ATTITUDE, MSG_LOCAL_POSITION_NED = 30, 32

#: HEARTBEAT.autopilot of a component that is no flight controller (ground stations, companions).
MAV_AUTOPILOT_INVALID = 8


def is_autopilot_heartbeat(msg: Any) -> bool:
    """True for a HEARTBEAT sent by a flight controller (its ``autopilot`` field names one).

    Ground stations (MAVProxy, QGroundControl) and companion computers, this daemon
    included, send MAV_AUTOPILOT_INVALID.
    """
    return msg.get_type() == "HEARTBEAT" and int(msg.autopilot) != MAV_AUTOPILOT_INVALID


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_ned_body(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """(3, 3) body FRD axes as columns in NED, from ATTITUDE's Euler angles (rad, Z-Y-X)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


@dataclass(frozen=True)
class CameraMount:
    """Where the (left) camera sits on the vehicle.

    ``offset_m``: (3,) camera centre in body FRD, m. ``pitch_deg``: tilt of the
    optical axis above the body's x axis, degrees (positive looks up).
    """

    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pitch_deg: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) camera axes as columns in body FRD."""
        # Rx(+a) in camera coordinates turns z toward -y, which is up.
        return R_BODY_CAMERA @ rot_x(math.radians(self.pitch_deg))


@dataclass(frozen=True)
class VehicleState:
    """The vehicle at one instant: NED position (m), Euler angles (rad), when it was received.

    ``t``: monotonic seconds of the *older* of the two messages it was built from.
    """

    position_ned: tuple[float, float, float]
    roll: float
    pitch: float
    yaw: float
    t: float = 0.0
    #: LOCAL_POSITION_NED's velocity (m/s, NED) and ATTITUDE's body rates (rad/s, roll, pitch, yaw).
    velocity_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)
    body_rates: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: When each message arrived (monotonic s); None: ``t``.
    t_position: float | None = None
    t_attitude: float | None = None

    def at(self, t: float) -> "VehicleState":
        """The state predicted for monotonic time ``t``: constant velocity and constant body rates.

        Each message is carried forward from its own arrival (never backward); the
        Euler angles move by the body rates turned into Euler rates (Z-Y-X).
        """
        tp = self.t if self.t_position is None else self.t_position
        ta = self.t if self.t_attitude is None else self.t_attitude
        dp, da = max(0.0, t - tp), max(0.0, t - ta)
        pos = tuple(float(x + v * dp) for x, v in zip(self.position_ned, self.velocity_ned))
        p, q, r = self.body_rates
        sr, cr = math.sin(self.roll), math.cos(self.roll)
        cp = max(1e-6, math.cos(self.pitch))
        roll_rate = p + (q * sr + r * cr) * math.tan(self.pitch)
        pitch_rate = q * cr - r * sr
        yaw_rate = (q * sr + r * cr) / cp
        return VehicleState(pos, self.roll + roll_rate * da, self.pitch + pitch_rate * da, self.yaw + yaw_rate * da,
                            t, self.velocity_ned, self.body_rates, t, t)

    def camera(self, mount: CameraMount) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (3, 3) camera axes in NED, camera centre (3,) NED m)."""
        r_nb = rotation_ned_body(self.roll, self.pitch, self.yaw)
        centre = np.asarray(self.position_ned, float) + r_nb @ np.asarray(mount.offset_m, float)
        return r_nb @ mount.rotation, centre


@dataclass(frozen=True)
class Anchor:
    """The scene's world frame in NED: ``origin_ned`` (3,) m and ``rotation`` (3, 3) world axes as columns."""

    origin_ned: np.ndarray
    rotation: np.ndarray

    @staticmethod
    def facing(tree_ned: Sequence[float], yaw: float, distance_m: float) -> "Anchor":
        """The level camera frame ``distance_m`` before ``tree_ned``, looking at it along heading ``yaw`` (rad)."""
        heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        return Anchor(np.asarray(tree_ned, float) - distance_m * heading, rot_z(yaw) @ R_BODY_CAMERA)

    @staticmethod
    def at_start(state: VehicleState, mount: CameraMount) -> "Anchor":
        """The rig's start pose, levelled (roll and pitch dropped, yaw kept)."""
        _, centre = state.camera(mount)
        return Anchor(centre, rot_z(state.yaw) @ R_BODY_CAMERA)

    @property
    def yaw(self) -> float:
        """Heading of the world's optical axis (rad from north, toward east)."""
        z = self.rotation[:, 2]
        return math.atan2(z[1], z[0])

    def to_world(self, point_ned: Sequence[float]) -> np.ndarray:
        return self.rotation.T @ (np.asarray(point_ned, float) - self.origin_ned)

    def pose(self, state: VehicleState, mount: CameraMount) -> Pose:
        """The rig pose in the scene's world frame for ``state``."""
        r_nc, centre = state.camera(mount)
        return Pose(self.rotation.T @ r_nc, self.rotation.T @ (centre - self.origin_ned))


@dataclass(frozen=True)
class SitlConfig:
    """How the simulated vehicle maps into the scene (``uav-depth sitl`` options).

    ``tree_ned_m``: (N, E, D) m of the target branch's nearest surface in the
    autopilot's local frame; None: ``scene.branch_distance_m`` in front of the start
    pose. ``approach_yaw_deg``: heading the tree is approached from (the scene's
    optical axis); None: from the start position toward the tree. ``pose_rate_hz``:
    rate requested for LOCAL_POSITION_NED and ATTITUDE. ``pose_timeout_s``: a pose
    older than this is not rendered (the frame source reports a loss instead).
    ``predict_max_s``: how far past the older pose message a frame's pose may be
    predicted (constant velocity and rates), so that the rendered frame shows the
    vehicle where it is when the frame is delivered, not where it was when the
    render began (0: never predicted; the frame is then as old as its pose).
    """

    tree_ned_m: tuple[float, float, float] | None = None
    approach_yaw_deg: float | None = None
    camera_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera_pitch_deg: float = 0.0
    pose_rate_hz: float = 50.0
    pose_timeout_s: float = 1.0
    predict_max_s: float = 0.1

    def __post_init__(self) -> None:
        for key, vec in (("--tree-ned", self.tree_ned_m), ("--camera-offset", self.camera_offset_m)):
            if vec is not None and (len(vec) != 3 or not all(math.isfinite(float(v)) for v in vec)):
                raise ConfigError(key, "must be three finite numbers (north, east, down / forward, right, down) "
                                  "in metres", vec)
        if self.approach_yaw_deg is not None and not -360.0 <= self.approach_yaw_deg <= 360.0:
            raise ConfigError("--approach-yaw-deg", "must be between -360 and 360", self.approach_yaw_deg)
        if not -90.0 < self.camera_pitch_deg < 90.0:
            raise ConfigError("--camera-pitch-deg", "must be above -90 and below 90", self.camera_pitch_deg)
        if not 1.0 <= self.pose_rate_hz <= 200.0:
            raise ConfigError("--pose-rate-hz", "must be between 1 and 200", self.pose_rate_hz)
        if not 0.05 <= self.pose_timeout_s <= 60.0:
            raise ConfigError("--pose-timeout-s", "must be between 0.05 and 60", self.pose_timeout_s)
        if not 0.0 <= self.predict_max_s <= 0.5:
            raise ConfigError("--pose-predict-max-s", "must be between 0 (no prediction) and 0.5", self.predict_max_s)

    def describe(self, distance_m: float) -> str:
        tree = ("tree %g m in front of the start pose" % distance_m if self.tree_ned_m is None
                else "tree at NED %s m" % list(self.tree_ned_m))
        yaw = "" if self.approach_yaw_deg is None else f", approached at heading {self.approach_yaw_deg:g} deg"
        return (f"sitl: {tree}{yaw}, camera at {list(self.camera_offset_m)} m pitched {self.camera_pitch_deg:g} deg, "
                f"pose at {self.pose_rate_hz:g} Hz (stale after {self.pose_timeout_s:g} s, predicted up to "
                f"{1000 * self.predict_max_s:.0f} ms ahead)")

    @property
    def mount(self) -> CameraMount:
        return CameraMount(tuple(float(v) for v in self.camera_offset_m), self.camera_pitch_deg)

    def anchor(self, start: VehicleState | None, distance_m: float) -> Anchor | None:
        """The scene's world frame; None while it depends on a start pose not yet known."""
        if self.tree_ned_m is not None and self.approach_yaw_deg is not None:
            return Anchor.facing(self.tree_ned_m, math.radians(self.approach_yaw_deg), distance_m)
        if start is None:
            return None
        if self.tree_ned_m is None:
            return Anchor.at_start(start, self.mount)
        _, centre = start.camera(self.mount)
        dn, de = self.tree_ned_m[0] - centre[0], self.tree_ned_m[1] - centre[1]
        if math.hypot(dn, de) < 1e-6:
            raise ConfigError("--tree-ned", "must not be straight above or below the start position when "
                              "--approach-yaw-deg is not given", list(self.tree_ned_m))
        return Anchor.facing(self.tree_ned_m, math.atan2(de, dn), distance_m)


class PoseTracker:
    """Latest LOCAL_POSITION_NED and ATTITUDE of the autopilot -> rig pose for the synthetic source.

    Feed it with :meth:`on_message` (from the MAVLink link's receive thread); call
    it as the source's ``pose_provider`` (from the frame thread). ``distance_m`` is
    the scene's ``branch_distance_m``. ``autopilot_sysid``: accept only that system
    (0: the first that sends a pose).
    """

    def __init__(self, config: SitlConfig, distance_m: float, clock: Callable[[], float] = time.monotonic,
                 autopilot_sysid: int = 0):
        self.config = config
        self.distance_m = distance_m
        self.clock = clock
        self.sysid = autopilot_sysid
        self._lock = threading.Lock()
        #: (position, velocity, arrival) and (angles, body rates, arrival)
        self._position: tuple[tuple[float, float, float], tuple[float, float, float], float] | None = None
        self._attitude: tuple[tuple[float, float, float], tuple[float, float, float], float] | None = None
        self._anchor: Anchor | None = config.anchor(None, distance_m)
        self.messages = 0
        #: When the vehicle was where the last pose returned puts it (monotonic s: the older message's
        #: arrival, or the time it was predicted for).
        self.pose_time: float | None = None
        #: The vehicle state the last pose returned was made from (predicted, when it was).
        self.pose_state: VehicleState | None = None
        #: The source may ask for a pose predicted to a time (``__call__``'s ``at``).
        self.predicts = config.predict_max_s > 0

    def on_message(self, msg: Any) -> None:
        """Take a LOCAL_POSITION_NED or ATTITUDE message (pymavlink); others are ignored."""
        kind = msg.get_type()
        if kind not in ("LOCAL_POSITION_NED", "ATTITUDE"):
            return
        sysid = msg.get_srcSystem()
        now = self.clock()
        with self._lock:
            if self.sysid == 0:
                self.sysid = sysid
            elif sysid != self.sysid:
                return
            if kind == "LOCAL_POSITION_NED":
                self._position = ((float(msg.x), float(msg.y), float(msg.z)),
                                  (float(msg.vx), float(msg.vy), float(msg.vz)), now)
            else:
                self._attitude = ((float(msg.roll), float(msg.pitch), float(msg.yaw)),
                                  (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed)), now)
            self.messages += 1
            if self._anchor is None and self._position is not None and self._attitude is not None:
                self._anchor = self.config.anchor(self._state_locked(), self.distance_m)

    def _state_locked(self) -> VehicleState | None:
        if self._position is None or self._attitude is None:
            return None
        (pos, vel, tp), (att, rates, ta) = self._position, self._attitude
        if not all(math.isfinite(v) for v in (*vel, *rates)):
            vel, rates = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)   # unknown rates: no prediction
        return VehicleState(pos, att[0], att[1], att[2], min(tp, ta), vel, rates, tp, ta)

    def state(self) -> VehicleState | None:
        with self._lock:
            return self._state_locked()

    def ready(self) -> bool:
        """True when a pose can be rendered now: both messages heard, the anchor known, the pose fresh."""
        with self._lock:
            state, anchor = self._state_locked(), self._anchor
        return state is not None and anchor is not None and self.clock() - state.t <= self.config.pose_timeout_s

    def waiting_for(self, autopilot: tuple[int, int] | None) -> str:
        """What is still missing before :meth:`ready`, in words (``autopilot``: the link's, if heard)."""
        with self._lock:
            pos, att = self._position is not None, self._attitude is not None
        who = ("no autopilot HEARTBEAT heard" if autopilot is None
               else "autopilot system %d component %d heard" % autopilot)
        if pos and att:
            return f"{who}; its pose is older than {self.config.pose_timeout_s:g} s"
        missing = " and ".join(n for n, have in (("LOCAL_POSITION_NED", pos), ("ATTITUDE", att)) if not have)
        return f"{who}; no {missing} yet"

    @property
    def anchor(self) -> Anchor | None:
        with self._lock:
            return self._anchor

    def tree_ned(self) -> np.ndarray | None:
        """Where the target branch's nearest surface is in NED (None before the anchor is known)."""
        a = self.anchor
        return None if a is None else a.origin_ned + a.rotation @ np.array([0.0, 0.0, self.distance_m])

    def __call__(self, t_s: float = 0.0, at: float | None = None) -> Pose:
        """The rig pose: the latest state's, or predicted for monotonic time ``at`` (at most
        ``predict_max_s`` past the older message; never before it). Raises SourceError while
        there is no fresh pose (nothing is rendered)."""
        with self._lock:
            state, anchor = self._state_locked(), self._anchor
        if state is None or anchor is None:
            raise SourceError("sitl: no pose from the autopilot yet (waiting for LOCAL_POSITION_NED and ATTITUDE)")
        age = self.clock() - state.t
        if age > self.config.pose_timeout_s:
            raise SourceError(f"sitl: the autopilot's pose is {age:.1f} s old (limit {self.config.pose_timeout_s:g} s)")
        if at is not None and self.predicts:
            state = state.at(min(at, state.t + self.config.predict_max_s)) if at > state.t else state
        self.pose_time, self.pose_state = state.t, state
        return anchor.pose(state, self.config.mount)


class ScriptedPose:
    """The synthetic source's scripted motion as a pose provider that refuses to fly toward an autopilot.

    ``scripted``: seconds -> Pose (the source config's ``scripted_pose``);
    ``autopilot``: returns the (system, component) of an autopilot heard on the
    link, or None. Once one is heard, nothing more is rendered (SourceError, so
    nothing is sent) unless ``force``.
    """

    def __init__(self, scripted: Callable[[float], Pose], autopilot: Callable[[], Any], force: bool = False):
        self.scripted = scripted
        self.autopilot = autopilot
        self.force = force

    def __call__(self, t_s: float = 0.0) -> Pose:
        ap = self.autopilot()
        if ap is not None and not self.force:
            raise SourceError("sitl: an autopilot (system %d component %d) is on the link: the scripted approach "
                              "stops (--force-scripted flies it anyway)" % tuple(ap))
        return self.scripted(t_s)
