"""uav-depth sitl --config FILE: the daemon flown by a simulated autopilot, with synthetic stereo.

It reads the autopilot's LOCAL_POSITION_NED and ATTITUDE over the same MAVLink
connection it sends DISTANCE_SENSOR on (asking for them with
MAV_CMD_SET_MESSAGE_INTERVAL), renders the tree scene of the config's synthetic
source from the vehicle's pose, and runs the real daemon on those frames. Without
an autopilot (none heard within --wait-s, or --scripted) the source's own scripted
approach stands in. Every processed frame goes into a CSV beside its ground truth,
so a run can be scored afterwards.

Exit codes as ``uav-depth run``: 0 after a clean stop, 78 for a bad config, 69 when
no frame could be rendered at start-up, 1 otherwise.
"""

from __future__ import annotations

import argparse

from uav_depth.cli.commands import run as run_command

def configure(p: argparse.ArgumentParser) -> None:
    run_command.configure(p)    # --config, --set, --params-file, --mavlink-url, --log-dir, --check, --log-level
    g = p.add_argument_group("simulation")
    g.add_argument("--tree-ned", nargs=3, type=float, metavar=("N", "E", "D"),
                   help="local NED position (m) of the target branch's nearest surface; default: "
                        "scene.branch_distance_m in front of the vehicle's start pose")
    g.add_argument("--approach-yaw-deg", type=float, metavar="DEG",
                   help="heading the tree is approached from (the scene's optical axis); default: from the start "
                        "position toward --tree-ned")
    g.add_argument("--camera-offset", nargs=3, type=float, default=(0.0, 0.0, 0.0), metavar=("F", "R", "D"),
                   help="camera position on the vehicle, body frame forward/right/down, m (default 0 0 0)")
    g.add_argument("--camera-pitch-deg", type=float, default=0.0, metavar="DEG",
                   help="camera tilt above the vehicle's forward axis, degrees (default 0)")
    g.add_argument("--pose-rate-hz", type=float, default=30.0, metavar="HZ",
                   help="rate requested for LOCAL_POSITION_NED and ATTITUDE (default 30)")
    g.add_argument("--pose-timeout-s", type=float, default=1.0, metavar="S",
                   help="an autopilot pose older than this is not rendered: no measurement is sent (default 1)")
    g.add_argument("--wait-s", type=float, default=30.0, metavar="S",
                   help="wait this long for the autopilot's first pose, then fly the scripted approach (default 30)")
    g.add_argument("--scripted", action="store_true",
                   help="no autopilot: fly the synthetic source's scripted approach (approach_speed_mps)")
    g.add_argument("--truth-log", metavar="FILE",
                   help="CSV of every processed frame: pose, ground truth, measured distance "
                        "(default: sitl-<time>.csv in logging.dir, or in the current directory)")


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.signals import install_once

    signals = install_once()

    import logging
    import time
    from pathlib import Path

    from uav_depth.cli.main import EXIT_CONFIG
    from uav_depth.cli.sources import SOURCES
    from uav_depth.daemon.config import load_run_config
    from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
    from uav_depth.daemon.mavlink_out import MavlinkLink
    from uav_depth.daemon.service import Service
    from uav_depth.sim.sitl import MSG_ATTITUDE, MSG_LOCAL_POSITION_NED, PoseRecorder, PoseTracker, \
        SitlConfig, TruthLog

    run_command.setup_logging(args.log_level)
    run_command.log_signals_installed(signals)
    log = logging.getLogger("uav_depth.sitl")
    err = run_command.error_line("sitl")
    try:
        config = load_run_config(args.config, run_command.overrides_from_args(args), sources=SOURCES)
        if config.source_kind != "synthetic":
            raise ConfigError("source.kind", "must be synthetic for uav-depth sitl (frames are rendered from the "
                              "vehicle's pose)", config.source_kind, str(args.config) if args.config else None)
        sitl = SitlConfig(tree_ned_m=tuple(args.tree_ned) if args.tree_ned else None,
                          approach_yaw_deg=args.approach_yaw_deg, camera_offset_m=tuple(args.camera_offset),
                          camera_pitch_deg=args.camera_pitch_deg, pose_rate_hz=args.pose_rate_hz,
                          pose_timeout_s=args.pose_timeout_s)
        if not 0 <= args.wait_s <= 3600:
            raise ConfigError("--wait-s", "must be between 0 and 3600", args.wait_s)
    except (ConfigError, CalibrationError, FileFormatError) as exc:
        err(exc)
        return EXIT_CONFIG
    if args.check:
        print(f"config valid: {config.summary()}; {sitl.describe(config.source.scene.branch_distance_m)}")
        return 0

    stop = signals.stop
    if stop.is_set():
        return run_command.stopped_before_start(signals, "sitl")
    svc = config.service
    link = MavlinkLink(config.mavlink, svc.reconnect_min_s, svc.reconnect_max_s)
    tracker = PoseTracker(sitl, config.source.scene.branch_distance_m)
    recorder = None
    if not args.scripted:
        link.subscribe("LOCAL_POSITION_NED", tracker.on_message)
        link.subscribe("ATTITUDE", tracker.on_message)
        # Remembered by the link and sent again when the autopilot (re)appears.
        link.request_message_interval(MSG_LOCAL_POSITION_NED, sitl.pose_rate_hz)
        link.request_message_interval(MSG_ATTITUDE, sitl.pose_rate_hz)
        link.start()
        log.info("waiting up to %.0f s for the autopilot's LOCAL_POSITION_NED and ATTITUDE on %s", args.wait_s,
                 config.mavlink.url)
        deadline = time.monotonic() + args.wait_s
        while tracker.anchor is None and time.monotonic() < deadline and not stop.wait(0.05):
            pass
        if stop.is_set():
            link.close()
            return 0
        if tracker.anchor is None:
            log.warning("no pose from an autopilot within %.0f s: flying the scripted approach instead", args.wait_s)
        else:
            tree = tracker.tree_ned()
            log.info("autopilot system %d: tree (target branch) at N %.2f E %.2f D %.2f m, approached at heading "
                     "%.0f deg", tracker.sysid, tree[0], tree[1], tree[2], sitl_heading_deg(tracker))
            recorder = PoseRecorder(tracker)
    try:
        service = Service(config, pose_provider=recorder, link=link)
    except (ConfigError, CalibrationError, FileFormatError) as exc:
        link.close()
        err(exc)
        return EXIT_CONFIG
    path = Path(args.truth_log) if args.truth_log else \
        Path(config.logging.dir or ".") / time.strftime("sitl-%Y%m%d-%H%M%S.csv")
    truth = TruthLog(path, service, recorder, tree_ned=tracker.tree_ned() if recorder else None)
    truth.start()

    def close_truth() -> None:
        truth.close()
        log.info("truth log %s: %s", path, truth.summary())

    return run_command.serve(service, signals, "sitl", cleanup=close_truth)


def sitl_heading_deg(tracker) -> float:
    import math

    anchor = tracker.anchor
    return math.degrees(anchor.yaw) % 360.0 if anchor is not None else float("nan")
