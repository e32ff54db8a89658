"""tuning.safety: the safety sweep that screens the tuner's choice and gates what it writes."""

from __future__ import annotations

from pathlib import Path

from uav_depth.core.params import load_params
from uav_depth.sim.sweep import VARIANTS, quick_sweep, render_with_truth
from uav_depth.tuning.frames import FrameData, FrameSet
from uav_depth.tuning.safety import SafetyScreen
from uav_depth.tuning.tune import TuneRequest, study_config


FLIGHT = load_params(Path(__file__).resolve().parents[2] / "deploy" / "params-flight.yaml")
#: The flight file tuned on 96 leafy scenes and six real pairs (2026-12-05), which the gate wrote before the sweep
#: existed: it reads the leafy frame below 2.7 % farther (and the twig frame 1.0 % farther; 2.6 % before the thin guard
#: took half a matched pixel, 2026-12-05).
T96 = FLIGHT.replace(**{"sgbm.p1": 12, "sgbm.p2": 649, "sgbm.disp12_max_diff": 325, "sgbm.pre_filter_cap": 62,
                        "sgbm.uniqueness_ratio": 1, "sgbm.speckle_window_size": 6, "sgbm.speckle_range": 35})


def _sweep_frame(key: str, cfg) -> FrameData:
    """``cfg`` rendered as the safety sweep renders its frames, keyed ``safety/<key>``."""
    left, right, truth_m, roi = render_with_truth(cfg)
    return FrameData(f"safety/{key}", left, right, branch_distance_m=truth_m, roi=roi,
                     focal_px=cfg.focal_px, baseline_m=cfg.baseline_m)


def _twig_frame() -> FrameData:
    """The quick sweep's leafy seed-0 branch at 2 m (truth 1.403 m, a twig), which the flight file reads within
    0.02 %."""
    return _sweep_frame("leafy-s0-2.00m", dict(quick_sweep())["leafy-s0-2.00m"])


def _farther_frame() -> FrameData:
    """The standard sweep's leafy seed-2 branch at 2.70 m (truth 2.020 m), which the flight file reads 0.78 % nearer
    and the 96-scene file 2.72 % farther."""
    return _sweep_frame("leafy-s2-2.70m", VARIANTS["leafy"](2.70, 2))


def _gate(request: TuneRequest, chosen, train: FrameSet):
    """The gate's verdict on ``chosen``, built as tune() builds its screen: the request's sweep and base."""
    return SafetyScreen(request.safety, request.base, train).check(chosen)


def _request(safety) -> TuneRequest:
    return TuneRequest("unused", study_config("random", None, None, None, 4, 1, 1, 0), FLIGHT, "unused",
                       safety=safety)


def test_the_safety_sweep_refuses_a_candidate_that_reads_a_sweep_frame_farther():
    """A file the gate wrote before the sweep existed (the flight file tuned on 96 leafy scenes and six real
    pairs, 2026-12-05): it reads the sweep's leafy seed-2 branch at 2.70 m (truth 2.020 m) 2.72 % farther; the
    flight file it started from reads it within 2 %. The sweep here is that one real frame."""
    flight, tuned, frame = FLIGHT, T96, _farther_frame()
    left, right = frame.left, frame.right
    sweep = FrameSet("safety", (frame,))
    seen = []
    request = _request(lambda sample: seen.append(sample) or sweep)
    check = _gate(request, tuned, FrameSet("train", (frame,)))
    assert (check.base, check.tuned, check.frames) == (0, 1, 1)
    assert check.reason == ("the tuned parameters read 1 of the 1 safety-sweep frame(s) farther than the truth by "
                            "more than 2 %, the base 0; the tuned parameters read the 1 leafy safety-sweep frame(s) "
                            "both read with a median absolute error of 2.72 %, above 1.1 x the base's 0.78 % + 0.25")
    assert (round(check.base_median, 2), round(check.tuned_median, 2)) == (0.78, 2.72)
    assert seen == [frame]                    # rendered at the rig of the log's calibrated frames
    # nothing to check when the base is kept, or when no frame of the log has a calibration
    assert _gate(request, flight, FrameSet("train", (frame,))) is None
    uncalibrated = FrameData("log/0", left, right)
    assert _gate(request, tuned, FrameSet("train", (uncalibrated,))) is None
    # a log of mixed rigs: the sweep is rendered at the rig most of its frames share, not its first frame's
    other = FrameData("real/0", left[:370, :413], right[:370, :413], focal_px=1246.7, baseline_m=0.16)
    seen.clear()
    _gate(request, tuned, FrameSet("train", (other, uncalibrated, frame, frame)))
    assert seen == [frame]


def test_the_safety_screen_sets_a_farther_or_a_less_accurate_candidate_aside(monkeypatch):
    """The screen of the held-out choice on the quick sweep's leafy seed-0 branch at 2 m (truth 1.403 m, a twig),
    which the flight file reads within 0.02 %. The 96-scene file above reads it 1.0 % farther: within 2 %, but less
    accurate than the base allows (1.1 x 0.02 + 0.25 %): set aside. The runner-up of the tune on leafy scenes and
    near-range frames (2026-12-05; the best five read this frame 3.5 % farther) reads it 1.4 % nearer: not farther,
    but less accurate than the base allows (1.1 x 0.02 + 0.25 %), and on the 330-frame sweep its median error is
    1.58 % against the flight file's 1.15 %: set aside too. A candidate that reads as the base passes. The sweep is
    rendered once, each parameter set read once."""
    flight, unsafe = FLIGHT, T96
    nearer = flight.replace(**{"sgbm.p1": 11, "sgbm.p2": 741, "sgbm.disp12_max_diff": 107, "sgbm.pre_filter_cap": 57,
                               "sgbm.uniqueness_ratio": 2, "sgbm.speckle_window_size": 39, "sgbm.speckle_range": 315})
    frame = _twig_frame()
    left, right = frame.left, frame.right
    renders, phases, reads = [], [], []
    request = _request(lambda sample: renders.append(sample) or FrameSet("safety", (frame,)))
    screen = SafetyScreen(request.safety, flight, FrameSet("train", (frame,)), phases.append)
    assert screen.active and renders == []                   # nothing rendered before a candidate needs it
    assert screen.reject(unsafe.to_dict()) == ("unsafe: reads the 1 leafy safety-sweep frame(s) both read with a "
                                               "median absolute error of 1.01 %, above 1.1 x the base's 0.02 % + 0.25")
    assert screen.reject(nearer.to_dict()) == ("unsafe: reads the 1 leafy safety-sweep frame(s) both read with a "
                                               "median absolute error of 1.40 %, above 1.1 x the base's 0.02 % + 0.25")
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


def test_a_worse_nominal_case_fails_the_sweep_even_when_the_pooled_median_is_better(monkeypatch):
    """The accuracy rule is per scene variant: a candidate that reads leafy frames better must not hide a worse
    plain branch (2026-12-05: a tuned file read the sweep's plain branch 2.18 % off against the flight file's
    1.34 %, passed pooled by 0.002 point, and read the real pairs worse). The readings are scripted per parameter
    set; what is tested is the verdict on them."""
    import numpy as np

    blank = np.zeros((8, 8), np.uint8)
    frames = tuple(FrameData(f"safety/{v}-s10-{i}m", blank, blank, branch_distance_m=1.0, focal_px=700.0,
                             baseline_m=0.063) for v, n in (("plain", 4), ("leafy", 8)) for i in range(n))
    base_err = {"plain": 0.010, "leafy": 0.010}
    tuned_err = {"plain": 0.022, "leafy": 0.005}

    def readings(params, frame_set):
        err = base_err if params == FLIGHT else tuned_err
        return [1.0 - err[f.key.split("/")[1].split("-")[0]] for f in frame_set.frames]   # nearer: never farther
    monkeypatch.setattr("uav_depth.tuning.safety.branch_distances", readings)
    screen = SafetyScreen(lambda sample: FrameSet("safety", frames), FLIGHT, FrameSet("train", frames[:1]))
    check = screen.check(T96)
    assert (check.base, check.tuned) == (0, 0)
    assert check.tuned_median < check.base_median                       # pooled, the candidate looks better
    assert check.reason == ("the tuned parameters read the 4 plain safety-sweep frame(s) both read with a median "
                            "absolute error of 2.20 %, above 1.1 x the base's 1.00 % + 0.25")
    tuned_err["plain"] = 0.013                                           # within 1.1 x 1.00 + 0.25 = 1.35 %
    assert SafetyScreen(lambda sample: FrameSet("safety", frames), FLIGHT, FrameSet("train", frames[:1])).check(
        T96).reason is None
