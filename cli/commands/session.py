"""uav-depth session import DIR OUT: a folder of stereo pairs -> a session in the log layout.

Pairs are found by name, in this order: ``left/NAME`` with ``right/NAME``;
``NAME_left.EXT`` with ``NAME_right.EXT`` (also ``_l``/``_r``, ``_L``/``_R``);
one pair per sub-folder as ``left.EXT``/``right.EXT``, ``im0``/``im1`` (Middlebury
2014) or ``view1``/``view5`` (Middlebury 2006). Frames are numbered in name order;
each frame's meta records the name it came from. The calibration comes from
``--calibration FILE`` or from ``--focal-px`` and ``--baseline-m`` (the size from the
images). Exit codes: 0 done; 73 OUT already holds a session (``--overwrite``
replaces it); 78 no pairs, a missing partner or a bad calibration; 1 an unreadable
image or pairs of different sizes (nothing is written then).
"""

from __future__ import annotations

import argparse

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
_SIDE_SUFFIXES = (("_left", "_right"), ("_l", "_r"), ("_L", "_R"))
_FOLDER_PAIRS = (("left", "right"), ("im0", "im1"), ("view1", "view5"))


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    imp = sub.add_parser("import", help="make a session from a folder of stereo pairs",
                         description=__doc__.split("\n\n")[1] if __doc__ else None)
    imp.add_argument("source", help="folder of stereo pairs (rectified, or raw with a full calibration)")
    imp.add_argument("out", help="session directory to write")
    imp.add_argument("--calibration", metavar="FILE", help="calibration file (focal_px, baseline_m, width, height; "
                                                           "K, D, R, T for raw pairs)")
    imp.add_argument("--focal-px", type=float, help="instead of --calibration: focal length of the rectified pair, px")
    imp.add_argument("--baseline-m", type=float, help="instead of --calibration: baseline, m")
    imp.add_argument("--overwrite", action="store_true", help="replace a session already at OUT (else exit 73)")


def find_pairs(folder):
    """[(name, left path, right path)] in name order; ConfigError when none or a partner is missing."""
    from pathlib import Path

    from uav_depth.core.errors import ConfigError

    root = Path(folder)
    if not root.is_dir():
        raise ConfigError("source", "must be a folder of stereo pairs", str(root))
    images = lambda d: sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)  # noqa: E731
    if (root / "left").is_dir() and (root / "right").is_dir():
        pairs = []
        for lp in images(root / "left"):
            rp = root / "right" / lp.name
            if not rp.exists():
                raise ConfigError("source", f"has left/{lp.name} without right/{lp.name}", str(root))
            pairs.append((lp.stem, lp, rp))
        if pairs:
            return pairs
    files = images(root)
    for ls, rs in _SIDE_SUFFIXES:
        lefts = [p for p in files if p.stem.endswith(ls)]
        if lefts:
            pairs = []
            for lp in lefts:
                rp = lp.with_name(lp.stem[: -len(ls)] + rs + lp.suffix)
                if not rp.exists():
                    raise ConfigError("source", f"has {lp.name} without {rp.name}", str(root))
                pairs.append((lp.stem[: -len(ls)], lp, rp))
            return pairs
    pairs = []
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        subimgs = {p.stem: p for p in images(sub)}
        for ln, rn in _FOLDER_PAIRS:
            if ln in subimgs and rn in subimgs:
                pairs.append((sub.name, subimgs[ln], subimgs[rn]))
                break
    if not pairs:
        raise ConfigError("source", "holds no stereo pairs (left/ + right/, NAME_left + NAME_right, or one "
                                    "pair per sub-folder: left/right, im0/im1, view1/view5)", str(root))
    return pairs


def run(args: argparse.Namespace) -> int:
    import time

    import cv2

    from uav_depth.cli.progress import Progress
    from uav_depth.core.calibration import Calibration, load_calibration
    from uav_depth.core.errors import ConfigError, FileFormatError
    from uav_depth.core.session import SessionWriter, prepare_output

    pairs = find_pairs(args.source)
    if args.calibration and (args.focal_px or args.baseline_m):
        raise ConfigError("--calibration", "cannot be combined with --focal-px/--baseline-m", args.calibration)
    if not args.calibration and not (args.focal_px and args.baseline_m):
        raise ConfigError("--calibration", "is required (or both --focal-px and --baseline-m)", None)
    first = cv2.imread(str(pairs[0][1]), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise FileFormatError(f"{pairs[0][1]}: missing or not a readable image")
    h, w = first.shape[:2]
    if args.calibration:
        calib = load_calibration(args.calibration)
        if (calib.width, calib.height) != (w, h):
            raise ConfigError("--calibration", f"is for {calib.width}x{calib.height} but the pairs are {w}x{h}",
                              args.calibration)
    else:
        calib = Calibration(focal_px=args.focal_px, baseline_m=args.baseline_m, width=w, height=h)
    prepare_output(args.out, args.overwrite)

    def load(lp, rp):
        imgs = cv2.imread(str(lp), cv2.IMREAD_UNCHANGED), cv2.imread(str(rp), cv2.IMREAD_UNCHANGED)
        for path, img in zip((lp, rp), imgs):
            if img is None:
                raise FileFormatError(f"{path}: missing or not a readable image")
            if img.shape[:2] != (h, w):
                raise FileFormatError(f"{path}: {img.shape[1]}x{img.shape[0]}, but {pairs[0][1].name} is {w}x{h}: "
                                      "a session has one size (one calibration); import each size on its own")
        return imgs

    progress = Progress()
    progress.phase(f"checking {len(pairs)} pairs {w}x{h} in {args.source} (nothing is written before)")
    t0 = time.monotonic()
    for i, (_, lp, rp) in enumerate(pairs):     # check every pair before writing anything
        load(lp, rp)
        progress.step("pairs checked", i + 1, len(pairs))
    progress.phase(f"writing {len(pairs)} pairs into {args.out}")
    writer = SessionWriter(args.out, calib)
    for i, (name, lp, rp) in enumerate(pairs):
        left, right = load(lp, rp)
        writer.write(i, left, right, meta={"imported_from": str(lp), "name": name})
        progress.step("pairs written", i + 1, len(pairs))
    print(f"imported {len(pairs)} pairs {w}x{h} into {args.out} (f {calib.focal_px:g} px, B {calib.baseline_m:g} m) "
          f"in {time.monotonic() - t0:.1f} s; next: uav-depth check-rig {args.out}, uav-depth reference import "
          f"{args.out} --from DIR")
    return 0
