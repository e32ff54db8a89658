"""The outlier gate: a jump away waits for confirmation, a nearer reading passes at once, too close is held."""

from uav_depth.core.ranging import OutlierGate


def test_outlier_gate_holds_a_single_jump_away_and_accepts_a_confirmed_one():
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2, forget_s=1.0)
    assert gate.accept(1.00, 0.0) and gate.accept(1.02, 0.1)
    assert not gate.accept(2.00, 0.2)          # a single-frame jump away is held back
    assert gate.accept(1.01, 0.3)              # and forgotten when the next frame agrees with history
    assert not gate.accept(1.60, 0.4)
    assert gate.accept(1.61, 0.5)              # confirmed by a second frame: accepted
    assert gate.accept(3.0, 2.0)               # after forget_s without data, anything goes
    assert OutlierGate(0.0, 2).accept(1.0, 0.0) and OutlierGate(0.0, 2).accept(5.0, 0.1)


def test_outlier_gate_lets_a_nearer_reading_through_at_once():
    """For a drone a sudden nearer object must win now: only a jump away needs confirming."""
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=3, forget_s=1.0)
    assert gate.accept(2.0, 0.0)
    assert gate.accept(0.6, 0.1)               # 70 % nearer, first frame: accepted
    assert gate.accept(0.3, 0.2)
    assert not gate.accept(0.9, 0.3)           # back away: held
    assert gate.accept(0.25, 0.4)              # nearer again: at once, and the pending jump is dropped
    assert not gate.accept(0.9, 0.5) and not gate.accept(0.9, 0.6) and gate.accept(0.9, 0.7)


def test_outlier_gate_after_too_close_holds_a_jump_away():
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2, forget_s=1.0)
    assert gate.accept(0.5, 0.0)
    gate.too_close(0.28, 0.1)
    assert not gate.accept(1.5, 0.2)           # from "nearer than 0.28 m" to 1.5 m in one frame: held
    assert gate.accept(0.3, 0.3)


def test_a_blank_frame_right_after_too_close_stays_too_close():
    gate = OutlierGate(max_jump_rel=0.2, confirm_frames=2, forget_s=1.0)
    from uav_depth.core.ranging import Measurement

    blank = Measurement(None, valid_fraction=0.01, reason="nothing matched")
    assert not gate.near(blank, 0.28, 0.0).too_close               # blank from the start: no measurement
    gate.near(Measurement(None, too_close=True, reason="near pass"), 0.28, 0.1)
    assert gate.near(blank, 0.28, 0.2).too_close                   # the object now fills the view
    assert gate.near(blank, 0.28, 1.1).too_close                   # still, frame after frame
    assert not gate.near(blank, 0.28, 2.5).too_close               # forget_s without evidence: unknown
    sparse = Measurement(None, valid_fraction=0.5, reason="no object")
    gate.near(Measurement(None, too_close=True, reason="near pass"), 0.28, 3.0)
    assert not gate.near(sparse, 0.28, 3.1).too_close              # half the ROI measured: not blank
