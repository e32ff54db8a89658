"""What the fine pass costs: `uav-depth bench`'s own timing loop with the flight file as it flies, with and
without ``compute.fine_disparities``, and the naive pipeline, interleaved frame by frame in one run.

    .venv/bin/python bench/fine_cost.py                      # 4 frames, 6 rounds, naive 2 rounds
    .venv/bin/python bench/fine_cost.py --frames 12 --rounds 20 --json
"""

from __future__ import annotations

import argparse
import json

from uav_depth.cli.benchmark import Variant, format_report, machine, make_frames, run
from uav_depth.core.params.flight import flight_params
from uav_depth.core.params import DEFAULT_PARAMS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--naive-rounds", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    flight = flight_params()
    variants = [Variant("naive", DEFAULT_PARAMS, args.naive_rounds),
                Variant("flight-coarse", flight.replace(**{"compute.fine_disparities": 0}), args.rounds, flies=True,
                        note="as it flies, fine pass off"),
                Variant("flight", flight, args.rounds, flies=True, note="as it flies (fine pass on)")]
    frames = make_frames(args.frames, 1280, 720, 0)
    out = run(frames, variants)
    out["machine"] = machine()
    out["frames"] = {"n": len(frames), "width": 1280, "height": 720, "truth_m": [f.truth_m for f in frames],
                     "render_s_per_pair": 0.0}
    if args.json:
        print(json.dumps(out, indent=1, default=str))
        return
    print(format_report(out))


if __name__ == "__main__":
    main()
