"""uav-depth sitl --config FILE: the daemon flown by a simulated autopilot, with synthetic stereo.

It reads the autopilot's LOCAL_POSITION_NED and ATTITUDE over the same MAVLink
connection it sends DISTANCE_SENSOR on (asking for them with
MAV_CMD_SET_MESSAGE_INTERVAL), renders the tree scene of the config's synthetic
source from the vehicle's pose, and runs the real daemon on those frames. Every
processed frame goes into a CSV beside its ground truth, so a run can be scored
afterwards.

No pose, no distance: the rig moves only with the autopilot's pose. Until the
first fresh pose arrives, and whenever it goes stale, nothing is rendered and no
distance is sent (the daemon is blind, as with a lost camera). There is no
fallback: the source's scripted approach flies only with ``--scripted``, and
never toward a link that carries an autopilot's HEARTBEAT (an autopilot fed
made-up distances flies on them) unless ``--force-scripted`` is given as well.

Exit codes as ``uav-depth run``: 0 after a clean stop, 78 for a bad config or
``--scripted`` toward an autopilot, 69 when no pose came within ``--wait-s`` or no
frame could be rendered at start-up, 1 otherwise.
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
    g.add_argument("--pose-rate-hz", type=float, default=50.0, metavar="HZ",
                   help="rate requested for LOCAL_POSITION_NED and ATTITUDE (default 50: a frame's pose is at most "
                        "20 ms old when its render starts)")
    g.add_argument("--pose-timeout-s", type=float, default=1.0, metavar="S",
                   help="an autopilot pose older than this is not rendered: no measurement is sent (default 1)")
    g.add_argument("--pose-predict-max-s", type=float, default=0.1, metavar="S",
                   help="render each frame at the pose predicted (constant velocity and rates) for when its render "
                        "is done, at most S s past the latest pose message, so the frame shows where the vehicle "
                        "is when the daemon gets it (default 0.1; 0: the pose as received, the render's time then "
                        "counts as latency)")
    g.add_argument("--wait-s", type=float, default=0.0, metavar="S",
                   help="give up (exit 69) when the autopilot's first pose has not come within S s; nothing is "
                        "sent meanwhile (default 0: wait as long as it takes; ArduPilot SITL streams its pose "
                        "about 40 s after boot)")
    g.add_argument("--scripted", action="store_true",
                   help="no autopilot: fly the synthetic source's scripted approach (approach_speed_mps); refused "
                        "when an autopilot's HEARTBEAT is heard on the link")
    g.add_argument("--force-scripted", action="store_true",
                   help="with --scripted: fly the scripted approach even toward an autopilot, which then receives "
                        "made-up distances (never on a vehicle that flies)")
    g.add_argument("--listen-s", type=float, default=2.5, metavar="S",
                   help="with --scripted: listen this long for an autopilot's HEARTBEAT before flying (default 2.5)")
    g.add_argument("--render", choices=("reads", "full"), default="reads",
                   help="reads (default): ray-cast only the part of each frame the flight pipeline reads (its "
                        "crops and the ranging ROI; the rest is black), whenever nothing else uses the frame "
                        "(live view, OBSTACLE_DISTANCE, rig check and frame logging off); full: every pixel")
    g.add_argument("--truth-log", metavar="FILE",
                   help="CSV of every processed frame: pose, ground truth, measured distance "
                        "(default: sitl-<time>.csv in logging.dir, or in the current directory)")


def run(args: argparse.Namespace) -> int:
    from uav_depth.cli.signals import install_once

    signals = install_once()

    from uav_depth.cli.exit_codes import EXIT_CONFIG
    from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
    from uav_depth.daemon.link.endpoint import MavlinkLink

    run_command.setup_logging(args.log_level)
    err = run_command.error_line("sitl")
    try:
        config, sitl = load_config(args)
    except (ConfigError, CalibrationError, FileFormatError) as exc:
        err(exc)
        return EXIT_CONFIG
    if args.check:
        print(f"config valid: {config.summary()}; {sitl.describe(config.source.scene.branch_distance_m)}"
              + ("; scripted approach" if args.scripted else ""))
        return 0
    if signals.stop.is_set():
        return run_command.stopped_before_start(signals, "sitl")
    svc = config.service
    try:
        link = MavlinkLink(config.mavlink, svc.reconnect_min_s, svc.reconnect_max_s)   # reads the signing key
    except ConfigError as exc:
        err(exc)
        return EXIT_CONFIG
    refused: list[str] = []
    wait = listen_for_autopilot if args.scripted else wait_for_pose
    pose_provider, tracker, code = wait(args, config, sitl, link, signals.stop, err, refused)
    if code is not None:
        return code
    return fly(args, config, link, pose_provider, tracker, signals, err, refused)


def load_config(args: argparse.Namespace):
    """(RunConfig, SitlConfig) from the arguments; ConfigError naming what is wrong."""
    from uav_depth.cli.sources import SOURCES
    from uav_depth.core.errors import ConfigError
    from uav_depth.daemon.config import load_run_config
    from uav_depth.sim.sitl import SitlConfig

    config = load_run_config(args.config, run_command.overrides_from_args(args), sources=SOURCES)
    if config.source_kind != "synthetic":
        raise ConfigError("source.kind", "must be synthetic for uav-depth sitl (frames are rendered from the "
                          "vehicle's pose)", config.source_kind, str(args.config) if args.config else None)
    sitl = SitlConfig(tree_ned_m=tuple(args.tree_ned) if args.tree_ned else None,
                      approach_yaw_deg=args.approach_yaw_deg, camera_offset_m=tuple(args.camera_offset),
                      camera_pitch_deg=args.camera_pitch_deg, pose_rate_hz=args.pose_rate_hz,
                      pose_timeout_s=args.pose_timeout_s, predict_max_s=args.pose_predict_max_s)
    if not 0 <= args.wait_s <= 3600:
        raise ConfigError("--wait-s", "must be between 0 (no limit) and 3600", args.wait_s)
    if not 0 <= args.listen_s <= 60:
        raise ConfigError("--listen-s", "must be between 0 and 60", args.listen_s)
    if args.force_scripted and not args.scripted:
        raise ConfigError("--force-scripted", "only goes with --scripted", True)
    return config, sitl


def listen_for_autopilot(args, config, sitl, link, stop, err, refused):
    """--scripted: listen for an autopilot first; (pose provider, None, exit code or None to fly)."""
    import logging
    import time

    from uav_depth.cli.exit_codes import EXIT_CONFIG
    from uav_depth.sim.sitl import ScriptedPose, is_autopilot_heartbeat

    log = logging.getLogger("uav_depth.sitl")

    def autopilot_heard(msg) -> None:   # on the link's thread: only note it and stop
        if is_autopilot_heartbeat(msg) and not args.force_scripted and not refused:
            refused.append(f"system {msg.get_srcSystem()} component {msg.get_srcComponent()} "
                           f"on {config.mavlink.url}")
            stop.set()
    link.subscribe("HEARTBEAT", autopilot_heard)
    link.start()
    log.info("scripted approach: listening %.1f s for an autopilot's HEARTBEAT on %s first", args.listen_s,
             config.mavlink.url)
    deadline = time.monotonic() + args.listen_s
    beat = heartbeats(link)
    while link.autopilot is None and not refused and not stop.wait(0.05) and time.monotonic() < deadline:
        beat()
    if refused or (link.autopilot is not None and not args.force_scripted):
        link.close()
        err(scripted_refusal(refused[0] if refused else "system %d component %d on %s" % (
            *link.autopilot, config.mavlink.url)))
        return None, None, EXIT_CONFIG
    if stop.is_set():
        link.close()
        return None, None, 0
    if link.autopilot is not None:
        log.warning("--force-scripted: the autopilot (system %d component %d) receives the scripted approach's "
                    "made-up distances", *link.autopilot)
    return ScriptedPose(config.source.scripted_pose, lambda: link.autopilot, args.force_scripted), None, None


def wait_for_pose(args, config, sitl, link, stop, err, refused):
    """Ask for the autopilot's pose and wait for it (no distance meanwhile); (pose provider, tracker, exit
    code or None to fly)."""
    import logging
    import time

    from uav_depth.cli.exit_codes import EXIT_UNAVAILABLE
    from uav_depth.sim.sitl import MSG_ATTITUDE, MSG_LOCAL_POSITION_NED, PoseTracker
    from uav_depth.sim.truthlog import PoseRecorder

    log = logging.getLogger("uav_depth.sitl")
    code = check_settings_on_connect(config, link, err)
    if code is not None:
        return None, None, code
    tracker = PoseTracker(sitl, config.source.scene.branch_distance_m)
    link.subscribe("LOCAL_POSITION_NED", tracker.on_message)
    link.subscribe("ATTITUDE", tracker.on_message)
    # Remembered by the link and sent again when the autopilot (re)appears.
    link.request_message_interval(MSG_LOCAL_POSITION_NED, sitl.pose_rate_hz)
    link.request_message_interval(MSG_ATTITUDE, sitl.pose_rate_hz)
    link.start()
    limit = f"up to {args.wait_s:g} s" if args.wait_s > 0 else "as long as it takes"
    log.info("waiting %s for the autopilot's LOCAL_POSITION_NED and ATTITUDE on %s; no distance is sent "
             "before (ArduPilot streams them once its EKF uses GPS)", limit, config.mavlink.url)
    t0 = time.monotonic()
    next_note = t0 + 10.0
    beat = heartbeats(link)
    while not tracker.ready() and not stop.wait(0.05):
        beat()
        now = time.monotonic()
        if args.wait_s > 0 and now - t0 > args.wait_s:
            link.close()
            err(f"no fresh pose (LOCAL_POSITION_NED and ATTITUDE) from an autopilot on {config.mavlink.url} "
                f"within --wait-s {args.wait_s:g} s ({tracker.waiting_for(link.autopilot)})")
            return None, tracker, EXIT_UNAVAILABLE
        if now >= next_note:
            log.info("still blind after %.0f s: %s", now - t0, tracker.waiting_for(link.autopilot))
            next_note = now + 10.0
    if stop.is_set():
        link.close()
        return None, tracker, 0
    tree = tracker.tree_ned()
    log.info("autopilot system %d: tree (target branch) at N %.2f E %.2f D %.2f m, approached at heading "
             "%.0f deg", tracker.sysid, tree[0], tree[1], tree[2], sitl_heading_deg(tracker))
    return PoseRecorder(tracker), tracker, None


def fly(args, config, link, pose_provider, tracker, signals, err, refused) -> int:
    """Run the service on frames rendered from ``pose_provider``, logging the truth beside each frame."""
    import logging
    import time
    from pathlib import Path

    from uav_depth.cli.exit_codes import EXIT_CONFIG
    from uav_depth.core.errors import CalibrationError, ConfigError, FileFormatError
    from uav_depth.daemon.service import Service
    from uav_depth.sim.truthlog import TruthLog

    log = logging.getLogger("uav_depth.sitl")
    try:
        service = Service(config, pose_provider=pose_provider, link=link)
    except (ConfigError, CalibrationError, FileFormatError) as exc:
        link.close()
        err(exc)
        return EXIT_CONFIG
    if args.render == "reads":
        why_full = full_frame_users(config)
        if why_full:
            log.info("rendering whole frames: %s reads them", " and ".join(why_full))
        else:
            service.source.read_window = pipeline_window(service)
            log.info("rendering only what the flight pipeline reads (--render full for every pixel)")
    path = Path(args.truth_log) if args.truth_log else \
        Path(config.logging.dir or ".") / time.strftime("sitl-%Y%m%d-%H%M%S.csv")
    recorder = pose_provider if tracker is not None else None
    truth = TruthLog(path, service, recorder, tree_ned=tracker.tree_ned() if recorder else None)
    truth.start()

    def close_truth() -> None:
        truth.close()
        log.info("truth log %s: %s", path, truth.summary())

    code = run_command.serve(service, signals, "sitl", cleanup=close_truth)
    if refused:
        err(scripted_refusal(refused[0]))
        return EXIT_CONFIG
    return code


def check_settings_on_connect(config, link, err) -> int | None:
    """Check the autopilot's settings when it is first heard, not when its pose comes (about 40 s later on
    ArduPilot, when the service and its send clock start): the range from the parameter file as run --check
    builds it. An exit code when the config cannot fly (as the service would say later), else None."""
    from uav_depth.cli.commands.run import exit_code
    from uav_depth.core.errors import UavDepthError
    from uav_depth.daemon.link.contract import stated_range_cm
    from uav_depth.daemon.link.settings import WireRange
    from uav_depth.daemon.link.settings_check import attach
    from uav_depth.daemon.link.vocabulary import orientation_code
    from uav_depth.daemon.preflight import preflight
    from uav_depth.daemon.sources import create_source

    try:
        limits = preflight(config, create_source(config.source)).limits
    except UavDepthError as exc:
        err(exc)
        return exit_code(exc)
    rng = WireRange(*stated_range_cm(limits), orientation_code(config.mavlink.orientation))
    attach(link, lambda: rng)
    return None


def heartbeats(link, state: str = "boot"):
    """A call for a wait loop that sends the daemon's HEARTBEAT once a second (docs/wire.md promises one a
    second whatever happens; the send clock, which sends it later, starts only with the service)."""
    import time

    from uav_depth.daemon.link.vocabulary import HEARTBEAT_PERIOD_S

    due = [0.0]

    def beat() -> None:
        now = time.monotonic()
        if now >= due[0]:
            link.heartbeat(state)
            due[0] = now + HEARTBEAT_PERIOD_S
    return beat


def full_frame_users(config) -> list[str]:
    """What in ``config`` reads whole frames (then every pixel is rendered)."""
    return [name for name, on in (("the live view", config.liveview.enabled),
                                  ("OBSTACLE_DISTANCE", config.obstacle_distance.enabled),
                                  ("the rig check", config.rig_check.interval_s > 0),
                                  ("frame logging", config.logging.dir is not None)) if on]


def pipeline_window(service):
    """``read_window`` for the synthetic source: what the service's current stage reads (None: all).

    Taken afresh for each frame from the stage flying then, so a parameter reload
    moves it; the one frame rendered just before a swap may lack pixels the new
    stage reads (black: nothing SGBM can match, so no reading from them).
    """
    from uav_depth.sim.source import pipeline_reads

    memo: dict[str, tuple[int, int, int, int]] = {}

    def window():
        stage, calib = service.stage, service.calibration
        if stage is None or calib is None:
            return None
        if stage.hash not in memo:
            memo.clear()
            memo[stage.hash] = pipeline_reads(stage.params, calib.width, calib.height)
        return memo[stage.hash]

    return window


def scripted_refusal(who: str):
    from uav_depth.core.errors import ConfigError

    return ConfigError("--scripted", "must not fly toward a link that carries an autopilot's HEARTBEAT (it would "
                       "receive made-up distances; add --force-scripted to insist)", who)


def sitl_heading_deg(tracker) -> float:
    import math

    anchor = tracker.anchor
    return math.degrees(anchor.yaw) % 360.0 if anchor is not None else float("nan")
