"""uav-depth reference import|onnx|show: give logged frames a reference disparity, and say where it came from."""

from __future__ import annotations

import argparse

_KINDS = ("synthetic", "import", "onnx", "device", "unknown")


def configure(p: argparse.ArgumentParser) -> None:
    from uav_depth.tuning.reference.options import (CHANNEL_ORDERS, FITS, FORMAT_INFO, NORMALIZATIONS, PROVIDERS,
                                                    SIGNS)

    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True

    def resume_options(q: argparse.ArgumentParser) -> None:
        q.add_argument("--overwrite", action="store_true",
                       help="replace existing references (default: skip frames that have one, so a rerun resumes)")
        q.add_argument("--replace", action="append", default=[], choices=_KINDS, metavar="KIND",
                       help="replace only existing references of this kind (repeatable), e.g. device")

    imp = sub.add_parser("import", help="attach existing reference maps to logged frames, matched by frame id",
                         description="Attach existing reference maps (any tool, a LiDAR projection, a public "
                                     "dataset) to logged frames. A sample SGBM run flags a wrong scale first.")
    imp.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    imp.add_argument("--from", dest="source", required=True, metavar="DIR", help="directory with the reference files")
    imp.add_argument("--pattern", help="file name per frame, with {id} (000000), {index} (0; {index:04d} works) and "
                                       "{session}; default {id} + the format's suffix")
    imp.add_argument("--format", choices=tuple(FORMAT_INFO),
                     help="; ".join(f"{k}: {doc}" for k, (_, _, doc) in FORMAT_INFO.items()) +
                          " (default: from the pattern's suffix, .npy or .pfm; npy without a pattern)")
    imp.add_argument("--scale", type=float, help="stored value / scale = disparity in px (default: the format's, "
                                                 "256 for kitti-png, else 1)")
    imp.add_argument("--no-check", action="store_true", help="skip the SGBM scale check")
    imp.add_argument("--check-frames", type=int, default=3, help="frames the scale check samples (default 3)")
    resume_options(imp)

    onx = sub.add_parser("onnx", help="compute references with an ONNX stereo network (onnxruntime)",
                         description="Run a user-supplied ONNX stereo network (RAFT-Stereo, CREStereo, HITNet "
                                     "exports) over a log. Frames with a reference are skipped unless --overwrite.")
    onx.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    onx.add_argument("--model", required=True, metavar="FILE.onnx", help="the ONNX model")
    onx.add_argument("--provider", choices=tuple(PROVIDERS), default="cpu", help="onnxruntime device (default cpu)")
    onx.add_argument("--input-size", metavar="WxH", help="model input size (must match a fixed-size model; default "
                                                          "for a free-size model: the frame rounded up to "
                                                          "--pad-multiple)")
    onx.add_argument("--fit", choices=FITS, help="frame to input: letterbox (keep aspect, pad), stretch, or pad "
                                                 "(no scaling). Default: pad for free-size models, else letterbox")
    onx.add_argument("--normalize", choices=tuple(NORMALIZATIONS), default="none",
                     help="; ".join(f"{k}: {v}" for k, v in NORMALIZATIONS.items()) + " (default none)")
    onx.add_argument("--channel-order", choices=CHANNEL_ORDERS, default="rgb", help="colour order the model expects "
                                                                                    "(default rgb)")
    onx.add_argument("--sign", choices=SIGNS, default="auto", help="auto negates flow-style (negative) outputs")
    onx.add_argument("--output", metavar="NAME", help="output to read when the model has several")
    onx.add_argument("--pad-multiple", type=int, default=32, help="free-size models: pad to a multiple of this "
                                                                  "(default 32)")
    onx.add_argument("--threads", type=int, default=0, help="onnxruntime intra-op threads (default: its own)")
    resume_options(onx)

    show = sub.add_parser("show", help="what the frames' references are and where they came from")
    show.add_argument("logdir", help="a session or a directory of sessions (log layout)")
    show.add_argument("--frames", action="store_true", help="one line per frame")
    show.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _progress(desc: str):
    from tqdm import tqdm

    return lambda it, total=None: tqdm(it, total=total, desc=desc, unit="frame", disable=None)


def run(args: argparse.Namespace) -> int:
    return {"import": _import, "onnx": _onnx, "show": _show}[args.action](args)


def _import(args: argparse.Namespace) -> int:
    from uav_depth.tuning.reference.importer import ImportConfig, import_references

    cfg = ImportConfig(args.source, format=args.format, pattern=args.pattern, scale=args.scale,
                       overwrite=args.overwrite, replace_kinds=tuple(args.replace), check=not args.no_check,
                       check_frames=args.check_frames)
    res = import_references(args.logdir, cfg, progress=lambda it: _progress("import")(it, len(it)))
    if res.check is not None:
        verdict = {True: "ok", False: "FLAGGED", None: "inconclusive"}[res.check.ok]
        print(f"scale check {verdict}: {res.check.reason}")
    print(f"imported {len(res.written)} references ({cfg.fmt.name}, scale {cfg.effective_scale:g}); "
          f"skipped {len(res.skipped)} frames that already had one; {len(res.missing)} frames without a file")
    return 0


def _onnx(args: argparse.Namespace) -> int:
    from uav_depth.tuning.reference.network import OnnxConfig, StereoNetwork, parse_size, run_onnx_references

    cfg = OnnxConfig(args.model, provider=args.provider,
                     input_size=parse_size(args.input_size) if args.input_size else None, fit=args.fit,
                     normalize=args.normalize, channel_order=args.channel_order, sign=args.sign, output=args.output,
                     pad_multiple=args.pad_multiple, overwrite=args.overwrite, replace_kinds=tuple(args.replace),
                     threads=args.threads)
    net = StereoNetwork(cfg)
    sig = net.signature
    size = "free" if sig.width is None or sig.height is None else f"{sig.width}x{sig.height}"
    print(f"model {cfg.model.name} (sha256 {cfg.model_sha256[:12]}): inputs {', '.join(sig.inputs)}, "
          f"{sig.channels} channel(s), size {size}; output {sig.output}; {net.provider}")
    res = run_onnx_references(args.logdir, cfg, progress=_progress("onnx"), network=net)
    print(f"wrote {len(res.written)} references; skipped {len(res.skipped)} frames that already had one"
          f"{' (--overwrite replaces them)' if res.skipped else ''}")
    return 0


def _show(args: argparse.Namespace) -> int:
    import json

    from uav_depth.core.session import iter_frames
    from uav_depth.tuning.reference.provenance import describe, read_provenance, summarize_references

    frames = list(iter_frames(args.logdir))
    summary = summarize_references(frames)
    if args.json:
        if args.frames:
            summary["per_frame"] = {f.key: read_provenance(f) for f in frames}
        print(json.dumps(summary, default=str))
        return 0
    print(f"{summary['frames']} frames: " + ", ".join(f"{n} {k}" for k, n in sorted(summary["by_kind"].items())))
    for src in summary["sources"]:
        print(f"  {src['frames']:>6} x {src['description']}")
    if args.frames:
        for f in frames:
            print(f"{f.key:<32}{describe(read_provenance(f))}")
    return 0
