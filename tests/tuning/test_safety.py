"""tuning.safety: the safety sweep that screens the tuner's choice and gates what it writes."""

from __future__ import annotations

from pathlib import Path

from uav_depth.core.params import load_params
from uav_depth.sim.sweep import quick_sweep, render_with_truth
from uav_depth.tuning.frames import FrameData, FrameSet
from uav_depth.tuning.safety import SafetyScreen
from uav_depth.tuning.tune import TuneRequest, study_config


def test_the_safety_screen_sets_a_farther_or_a_less_accurate_candidate_aside(monkeypatch):
    """The screen of the held-out choice on the same real frame, which the flight file reads within 0.02 %. The
    96-scene file above reads it 2.6 % farther: set aside. The runner-up of the tune on leafy scenes and near-range
    frames (2026-12-05; the best five read this frame 3.5 % farther) reads it 1.4 % nearer: not farther, but less
    accurate than the base allows (1.1 x 0.02 + 0.25 %), and on the 330-frame sweep its median error is 1.58 %
    against the flight file's 1.15 %: set aside too. A candidate that reads as the base passes. The sweep is
    rendered once, each parameter set read once."""
    flight = load_params(Path(__file__).resolve().parents[2] / "deploy" / "params-flight.yaml")
    unsafe = flight.replace(**{"sgbm.p1": 12, "sgbm.p2": 649, "sgbm.disp12_max_diff": 325, "sgbm.pre_filter_cap": 62,
                               "sgbm.uniqueness_ratio": 1, "sgbm.speckle_window_size": 6, "sgbm.speckle_range": 35})
    nearer = flight.replace(**{"sgbm.p1": 11, "sgbm.p2": 741, "sgbm.disp12_max_diff": 107, "sgbm.pre_filter_cap": 57,
                               "sgbm.uniqueness_ratio": 2, "sgbm.speckle_window_size": 39, "sgbm.speckle_range": 315})
    cfg = dict(quick_sweep())["leafy-s0-2.00m"]
    left, right, truth_m, roi = render_with_truth(cfg)
    frame = FrameData("safety/leafy-s0-2.00m", left, right, branch_distance_m=truth_m, roi=roi,
                      focal_px=cfg.focal_px, baseline_m=cfg.baseline_m)
    renders, phases, reads = [], [], []
    request = TuneRequest("unused", study_config("random", None, None, None, 4, 1, 1, 0), flight, "unused",
                          safety=lambda sample: renders.append(sample) or FrameSet("safety", (frame,)))
    screen = SafetyScreen(request.safety, flight, FrameSet("train", (frame,)), phases.append)
    assert screen.active and renders == []                   # nothing rendered before a candidate needs it
    assert screen.reject(unsafe.to_dict()).startswith("unsafe: reads 1 of the 1 safety-sweep frame(s) farther than "
                                                      "the truth by more than 2 %, the base 0; ")
    assert screen.reject(nearer.to_dict()) == ("unsafe: reads the 1 safety-sweep frame(s) both read with a median "
                                               "absolute error of 1.40 %, above 1.1 x the base's 0.02 % + 0.25")
    assert screen.reject(flight.to_dict()) is None
    check = screen.check(nearer)
    assert (check.base, check.tuned, check.frames) == (0, 0, 1) and "median absolute error of 1.40 %" in check.reason
    assert len(renders) == 1 and len(phases) == 1 and phases[0].startswith("the safety sweep: ")
    # each parameter set read once: base, unsafe, nearer
    monkeypatch.setattr("uav_depth.tuning.safety.branch_distances", lambda p, f: reads.append(p))
    screen.reject(unsafe.to_dict()), screen.check(nearer), screen.reject(flight.to_dict())
    assert reads == []
    # no sweep asked for, or no calibrated frame: inactive
    assert not SafetyScreen(None, flight, FrameSet("train", (frame,))).active
    assert not SafetyScreen(request.safety, flight, FrameSet("train", (FrameData("log/0", left, right),))).active
