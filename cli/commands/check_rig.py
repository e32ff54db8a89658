"""uav-depth check-rig SESSION | --config RUN.yaml: is the stereo pair still rectified?

Measures the vertical misalignment of the rectified pair from feature matches
(median, spread, worst corner, px) and the horizontal offset (disparity), pooled
over up to ``--frames`` frames, and says whether SGBM can work with it
(:mod:`uav_depth.core.rigcheck`). Exit codes: 0 the rig is fine; 3 misaligned
beyond the threshold; 4 too few feature matches to tell; 78 a bad config,
calibration or session.
"""

from __future__ import annotations

import argparse

from uav_depth.cli.exit_codes import EXIT_CANNOT_TELL, EXIT_MISALIGNED


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", nargs="?", help="a session directory (log layout: calibration.yaml, frames/)")
    p.add_argument("--config", metavar="FILE", help="instead of a session: live frames from this run config's source")
    p.add_argument("--frames", type=int, default=5, help="frames pooled (default 5)")
    p.add_argument("--threshold", type=float, default=None,
                   help="largest acceptable vertical misalignment, px (default 0.5)")


def _session_pairs(path: str, n: int):
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.rectify import Rectifier
    from uav_depth.core.session import Session

    session = Session(path)
    if not Session.is_session(session.path):
        raise ConfigError("session", "must be a session directory (calibration.yaml and frames/)", path)
    frames = session.frames()
    if not frames:
        raise ConfigError("session", "must hold at least one frame", path)
    rect = Rectifier(session.calibration())
    step = max(1, len(frames) // n)
    chosen = frames[::step][:n]
    return len(chosen), (rect(*rec.load_pair()) for rec in chosen)


def _live_pairs(config_path: str, n: int):
    import time

    from uav_depth.cli.sources import SOURCES
    from uav_depth.core.errors import CalibrationError, SourceError
    from uav_depth.core.rectify import Rectifier
    from uav_depth.daemon.config import load_run_config
    from uav_depth.daemon.sources import create_source

    cfg = load_run_config(config_path, sources=SOURCES)
    source = create_source(cfg.source)
    source.open()
    try:
        calib = cfg.calibration or source.calibration
        if calib is None:
            raise CalibrationError(f"source {cfg.source_kind} carries no calibration: set calibration: FILE")
        rect = Rectifier(calib)
        got, deadline = 0, time.monotonic() + 30.0
        while got < n:
            if time.monotonic() > deadline:
                raise SourceError(f"{source.describe()}: no frame within 30 s")
            frame = source.read(1.0)
            if frame is None:
                continue
            got += 1
            yield rect(frame.left, frame.right)
    finally:
        source.close()


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from uav_depth.cli.progress import Progress
    from uav_depth.core.errors import ConfigError
    from uav_depth.core.rigcheck import MAX_VERTICAL_PX, match_offsets, summarise

    if (args.session is None) == (args.config is None):
        raise ConfigError("check-rig", "takes a SESSION or --config FILE (one of them)",
                          args.session or args.config)
    if args.frames < 1:
        raise ConfigError("--frames", "must be at least 1", args.frames)
    total, pairs = _session_pairs(args.session, args.frames) if args.session else \
        (args.frames, _live_pairs(args.config, args.frames))
    progress = Progress()
    progress.phase(f"matching features in {total} frame(s) of {args.session or args.config}")
    rows, size, n = [], None, 0
    for left, right in pairs:
        rows.append(match_offsets(left, right))
        size = (left.shape[1], left.shape[0])
        n += 1
        progress.step("frames matched", n, total)
    offsets = np.concatenate(rows) if rows else np.zeros((0, 4))
    threshold = MAX_VERTICAL_PX if args.threshold is None else args.threshold
    check = summarise(offsets, size[0], size[1], threshold)
    print(f"{n} frame(s) {size[0]}x{size[1]}: {check.verdict()}")
    if check.ok is None:
        return EXIT_CANNOT_TELL
    return 0 if check.ok else EXIT_MISALIGNED
