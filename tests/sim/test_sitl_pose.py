"""SITL pose math: autopilot NED position + attitude -> the rig pose the scene renders."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from uav_depth.core.errors import ConfigError, SourceError
from uav_depth.sim.scene import Scene, SceneConfig
from uav_depth.sim.sitl import Anchor, CameraMount, PoseTracker, SitlConfig, VehicleState, rotation_ned_body

LEVEL = CameraMount()


def test_level_vehicle_at_the_anchor_is_the_identity_pose():
    for yaw in (0.0, 0.7, -2.5):
        anchor = Anchor.facing((10.0, -4.0, -3.0), yaw, 2.0)
        start = VehicleState(tuple(anchor.origin_ned), 0.0, 0.0, yaw)
        pose = anchor.pose(start, LEVEL)
        np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(pose.position, 0.0, atol=1e-12)
        np.testing.assert_allclose(anchor.to_world((10.0, -4.0, -3.0)), [0.0, 0.0, 2.0], atol=1e-12)


def test_flying_along_the_heading_moves_along_the_optical_axis():
    anchor = Anchor.facing((5.0, 5.0, -2.0), math.pi / 2, 3.0)          # approach heading east
    state = VehicleState((5.0, 3.0, -2.0), 0.0, 0.0, math.pi / 2)         # 1 m east of the anchor
    pose = anchor.pose(state, LEVEL)
    np.testing.assert_allclose(pose.position, [0.0, 0.0, 1.0], atol=1e-12)
    # Facing east: south is to the right (+x), up is -y; 1 m further east is 1 m further ahead.
    np.testing.assert_allclose(anchor.to_world((4.0, 3.0, -2.5)), [1.0, -0.5, 1.0], atol=1e-12)


def test_attitude_turns_the_camera_the_right_way():
    anchor = Anchor.facing((10.0, 0.0, 0.0), 0.0, 2.0)
    z = lambda roll, pitch, yaw: anchor.pose(VehicleState((8.0, 0.0, 0.0), roll, pitch, yaw), LEVEL).rotation  # noqa
    d = math.radians(10)
    # yaw right (toward east): the optical axis gains +x (right)
    np.testing.assert_allclose(z(0, 0, d)[:, 2], [math.sin(d), 0, math.cos(d)], atol=1e-12)
    # nose up: the optical axis gains -y (up)
    np.testing.assert_allclose(z(0, d, 0)[:, 2], [0, -math.sin(d), math.cos(d)], atol=1e-12)
    # roll right (right side down): the optical axis stays, camera x (right) gains +y (down)
    r = z(d, 0, 0)
    np.testing.assert_allclose(r[:, 2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(r[:, 0], [math.cos(d), math.sin(d), 0], atol=1e-12)
    for m in (z(0.3, -0.2, 1.1), rotation_ned_body(0.3, -0.2, 1.1)):
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)


def test_camera_mount_offset_and_tilt():
    anchor = Anchor.facing((10.0, 0.0, -1.0), 0.0, 2.0)
    state = VehicleState((7.0, 0.0, -1.0), 0.0, 0.0, 0.0)
    mount = CameraMount(offset_m=(0.2, 0.05, 0.1), pitch_deg=15.0)
    pose = anchor.pose(state, mount)
    # 0.2 m forward, 0.05 m right, 0.1 m below the vehicle's centre
    np.testing.assert_allclose(pose.position, [0.05, 0.1, -0.8], atol=1e-12)
    t = math.radians(15)
    np.testing.assert_allclose(pose.rotation[:, 2], [0, -math.sin(t), math.cos(t)], atol=1e-12)
    # the same tilt from the airframe instead: identical camera
    tilted = anchor.pose(VehicleState((7.0, 0.0, -1.0), 0.0, t, 0.0), CameraMount())
    np.testing.assert_allclose(tilted.rotation, pose.rotation, atol=1e-12)


@pytest.fixture(scope="module")
def scene():
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_distance_m=2.0, branch_angle_deg=0.0,
                      n_branches=0, noise_std=0.0, seed=3)
    return cfg, Scene(cfg)


def test_rendered_truth_follows_the_vehicle(scene):
    cfg, sc = scene
    tree = (20.0, 10.0, -4.0)
    anchor = Anchor.facing(tree, math.radians(30), cfg.branch_distance_m)
    for dist in (2.0, 1.2, 0.6):
        pos = np.asarray(tree) - dist * np.array([math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0])
        frame = sc.render(anchor.pose(VehicleState(tuple(pos), 0.0, 0.0, math.radians(30)), LEVEL))
        assert frame.nearest_branch_distance(cfg.center_roi) == pytest.approx(dist, rel=1e-3)


def test_pitching_up_moves_the_branch_down_in_the_image(scene):
    cfg, sc = scene
    anchor = Anchor.facing((2.0, 0.0, 0.0), 0.0, cfg.branch_distance_m)
    col = cfg.width // 2

    def branch_row(pitch_deg):
        frame = sc.render(anchor.pose(VehicleState((0.0, 0.0, 0.0), 0.0, math.radians(pitch_deg), 0.0), LEVEL))
        return float(np.nonzero(frame.branch_mask[:, col])[0].mean())

    level, up = branch_row(0.0), branch_row(5.0)
    assert level == pytest.approx((cfg.height - 1) / 2, abs=1.0)
    assert up - level == pytest.approx(cfg.focal_px * math.tan(math.radians(5.0)), abs=1.5)


def _parsed(msg, sysid=1, compid=1):
    """``msg`` as it arrives: packed by one pymavlink endpoint, parsed by another."""
    tx = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    rx = mavlink2.MAVLink(None)
    return rx.parse_char(msg.pack(tx))


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_pose_tracker_from_mavlink_messages():
    clock = Clock()
    tracker = PoseTracker(SitlConfig(tree_ned_m=None, pose_timeout_s=0.5), distance_m=3.0, clock=clock)
    with pytest.raises(SourceError, match="no pose from the autopilot yet"):
        tracker(0.0)
    tracker.on_message(_parsed(mavlink2.MAVLink_local_position_ned_message(0, 4.0, -2.0, -5.0, 0, 0, 0)))
    with pytest.raises(SourceError, match="no pose"):
        tracker(0.0)                                               # position without attitude
    yaw = math.radians(45)
    tracker.on_message(_parsed(mavlink2.MAVLink_attitude_message(0, 0.0, 0.0, yaw, 0, 0, 0)))
    np.testing.assert_allclose(tracker(0.0).position, 0.0, atol=1e-6)   # the start pose is the anchor
    np.testing.assert_allclose(tracker.tree_ned(), [4.0 + 3.0 * math.cos(yaw), -2.0 + 3.0 * math.sin(yaw), -5.0],
                               atol=1e-5)
    # another system's pose is ignored; the autopilot's next one moves the rig
    tracker.on_message(_parsed(mavlink2.MAVLink_local_position_ned_message(0, 99.0, 99.0, 0.0, 0, 0, 0), sysid=7))
    tracker.on_message(_parsed(mavlink2.MAVLink_local_position_ned_message(0, 4.0 + math.cos(yaw),
                                                                           -2.0 + math.sin(yaw), -5.0, 0, 0, 0)))
    np.testing.assert_allclose(tracker(0.0).position, [0.0, 0.0, 1.0], atol=1e-5)
    clock.t += 0.6                                                 # the autopilot went quiet
    with pytest.raises(SourceError, match="pose is 0.6 s old"):
        tracker(0.0)


def test_fixed_tree_is_approached_from_the_start_position():
    clock = Clock()
    tracker = PoseTracker(SitlConfig(tree_ned_m=(0.0, 10.0, -2.0)), distance_m=2.5, clock=clock)
    # The vehicle starts 10 m west of the tree, facing north: the approach heading is east anyway.
    tracker.on_message(_parsed(mavlink2.MAVLink_local_position_ned_message(0, 0.0, 0.0, -2.0, 0, 0, 0)))
    tracker.on_message(_parsed(mavlink2.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0, 0, 0)))
    assert tracker.anchor.yaw == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(tracker.tree_ned(), [0.0, 10.0, -2.0], atol=1e-9)
    pose = tracker(0.0)
    np.testing.assert_allclose(pose.position, [0.0, 0.0, -7.5], atol=1e-5)      # 10 m before the tree
    np.testing.assert_allclose(pose.rotation[:, 2], [-1.0, 0.0, 0.0], atol=1e-6)  # looking north = left


@pytest.mark.parametrize("kwargs, message", [
    (dict(tree_ned_m=(1.0, 2.0)), "--tree-ned must be three finite numbers"),
    (dict(camera_offset_m=(0.0, float("nan"), 0.0)), "--camera-offset must be three finite numbers"),
    (dict(camera_pitch_deg=90.0), "--camera-pitch-deg must be above -90 and below 90, but got 90.0"),
    (dict(pose_rate_hz=0.5), "--pose-rate-hz must be between 1 and 200, but got 0.5"),
    (dict(approach_yaw_deg=400.0), "--approach-yaw-deg must be between -360 and 360"),
    (dict(predict_max_s=0.6), "--pose-predict-max-s must be between 0 (no prediction) and 0.5, but got 0.6"),
], ids=["tree", "offset", "pitch", "rate", "yaw", "predict"])
def test_bad_sitl_settings(kwargs, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        SitlConfig(**kwargs)


def test_only_a_flight_controller_heartbeat_counts_as_an_autopilot():
    from uav_depth.sim.sitl import is_autopilot_heartbeat
    mav = mavlink2.MAVLink(None)
    hb = lambda mav_type, autopilot: _parsed(mav.heartbeat_encode(mav_type, autopilot, 0, 0, 4))  # noqa: E731
    assert is_autopilot_heartbeat(hb(2, 3))           # quadrotor, ArduPilot
    assert is_autopilot_heartbeat(hb(2, 12))          # quadrotor, PX4
    assert not is_autopilot_heartbeat(hb(6, 8))       # MAVProxy / QGroundControl: GCS, autopilot invalid
    assert not is_autopilot_heartbeat(hb(18, 8))      # a companion computer (this daemon)
    assert not is_autopilot_heartbeat(_parsed(mav.attitude_encode(0, 0, 0, 0, 0, 0, 0)))


def test_tracker_is_ready_only_with_a_fresh_pose_and_says_what_it_lacks():
    mav = mavlink2.MAVLink(None)
    now = [100.0]
    tracker = PoseTracker(SitlConfig(tree_ned_m=(5.0, 0.0, -3.0), pose_timeout_s=0.5), 2.0, clock=lambda: now[0])
    assert not tracker.ready()
    assert tracker.waiting_for(None) == "no autopilot HEARTBEAT heard; no LOCAL_POSITION_NED and ATTITUDE yet"
    tracker.on_message(_parsed(mav.local_position_ned_encode(0, 1.0, 0.0, -3.0, 0, 0, 0)))
    assert not tracker.ready()
    assert tracker.waiting_for((1, 1)) == "autopilot system 1 component 1 heard; no ATTITUDE yet"
    tracker.on_message(_parsed(mav.attitude_encode(0, 0, 0, 0, 0, 0, 0)))
    assert tracker.ready()
    now[0] += 0.6
    assert not tracker.ready()
    assert tracker.waiting_for((1, 1)) == "autopilot system 1 component 1 heard; its pose is older than 0.5 s"
    with pytest.raises(SourceError, match="old"):
        tracker()


def test_scripted_pose_stops_once_an_autopilot_is_heard():
    from uav_depth.sim.sitl import ScriptedPose
    from uav_depth.sim.scene import Pose
    heard = [None]
    scripted = ScriptedPose(lambda t: Pose.forward(0.1 * t), lambda: heard[0])
    np.testing.assert_allclose(scripted(2.0).position, Pose.forward(0.2).position)
    heard[0] = (1, 1)
    with pytest.raises(SourceError, match=r"autopilot \(system 1 component 1\) is on the link"):
        scripted(3.0)
    forced = ScriptedPose(lambda t: Pose.forward(0.1 * t), lambda: (1, 1), force=True)
    np.testing.assert_allclose(forced(3.0).position, Pose.forward(0.3).position)


def test_a_state_is_predicted_forward_at_constant_velocity_and_rates_never_backward():
    s = VehicleState((1.0, 2.0, -3.0), 0.0, 0.0, 0.5, t=10.0, velocity_ned=(2.0, -1.0, 0.5),
                     body_rates=(0.0, 0.0, 0.4), t_position=10.0, t_attitude=10.01)
    p = s.at(10.05)
    np.testing.assert_allclose(p.position_ned, (1.1, 1.95, -2.975))
    assert p.yaw == pytest.approx(0.5 + 0.4 * 0.04)                  # attitude from its own arrival
    assert p.t == p.t_position == p.t_attitude == 10.05
    back = s.at(9.0)                                                  # never extrapolated backward
    np.testing.assert_allclose(back.position_ned, s.position_ned)
    assert back.yaw == s.yaw
    # pitched, the body's yaw rate moves pitch and yaw through the Z-Y-X Euler rates
    tilted = VehicleState((0.0, 0.0, 0.0), math.radians(30), math.radians(20), 0.0, t=0.0,
                          body_rates=(0.0, 0.0, 1.0))
    q = tilted.at(0.01)
    assert q.pitch == pytest.approx(math.radians(20) - 0.01 * math.sin(math.radians(30)))
    assert q.yaw == pytest.approx(0.01 * math.cos(math.radians(30)) / math.cos(math.radians(20)))


def test_the_tracker_predicts_the_pose_for_the_time_asked_within_its_limit():
    clock = Clock()
    tracker = PoseTracker(SitlConfig(tree_ned_m=(10.0, 0.0, -3.0), approach_yaw_deg=0.0, predict_max_s=0.1),
                          distance_m=2.0, clock=clock)
    tracker.on_message(_parsed(mavlink2.MAVLink_local_position_ned_message(0, 4.0, 0.0, -3.0, 2.0, 0.0, 0.0)))
    tracker.on_message(_parsed(mavlink2.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
    assert tracker.predicts
    now = tracker(0.0)                                 # no time asked: the pose as received
    assert tracker.pose_time == 100.0
    ahead = tracker(0.0, at=100.04)                    # 2 m/s north for 40 ms: 8 cm nearer the tree
    assert tracker.pose_time == 100.04
    assert ahead.position[2] - now.position[2] == pytest.approx(0.08, abs=1e-6)
    assert tracker.pose_state.position_ned[0] == pytest.approx(4.08)
    far = tracker(0.0, at=101.0)                       # never further than predict_max_s past the pose
    assert tracker.pose_time == pytest.approx(100.1)
    assert far.position[2] - now.position[2] == pytest.approx(0.2, abs=1e-6)
    off = PoseTracker(SitlConfig(tree_ned_m=(10.0, 0.0, -3.0), approach_yaw_deg=0.0, predict_max_s=0.0),
                      distance_m=2.0, clock=clock)
    assert not off.predicts
    for msg in (mavlink2.MAVLink_local_position_ned_message(0, 4.0, 0.0, -3.0, 2.0, 0.0, 0.0),
                mavlink2.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)):
        off.on_message(_parsed(msg))
    np.testing.assert_allclose(off(0.0, at=100.04).position, now.position)
    assert off.pose_time == 100.0
