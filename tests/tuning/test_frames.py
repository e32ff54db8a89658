"""tuning.frames: the --holdout rules that split a log into train and held-out frames."""

from __future__ import annotations

from uav_depth.tuning.frames import split_records


def test_holdout_list_longer_than_a_file_name(tiny_session):
    """A long --holdout list of names (a log of many sessions) is a list, not a path: before, ``is_dir``
    raised OSError (file name too long) and the tune died with a traceback."""
    names = ",".join(["000003"] * 60)          # 419 characters, one path component: over NAME_MAX (255)
    assert len(names) > 255
    train, held = split_records(tiny_session / "s", names)
    assert [r.frame_id for r in held] == ["000003"]
    assert [r.frame_id for r in train] == ["000000", "000001", "000002"]


def test_holdout_directory_still_a_directory(tiny_session):
    train, held = split_records(tiny_session / "s", str(tiny_session / "s"))
    assert len(held) == 4 and train == []
