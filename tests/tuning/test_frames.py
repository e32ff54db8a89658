"""tuning.split: the --test and --holdout rules that split a log into training, validation and test frames."""

from __future__ import annotations

import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.core.session import iter_frames
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.tuning.split import hold_out, plan

from .conftest import TINY


def test_holdout_list_longer_than_a_file_name(tiny_session):
    """A long --holdout list of names (a log of many sessions) is a list, not a path: ``is_dir`` raises OSError
    (file name too long) on it, which must not end the tune with a traceback."""
    names = ",".join(["000003"] * 60)          # 419 characters, one path component: over NAME_MAX (255)
    assert len(names) > 255
    train, held = hold_out(list(iter_frames(tiny_session / "s")), names, "--holdout", 0.3)
    assert [r.frame_id for r in held] == ["000003"]
    assert [r.frame_id for r in train] == ["000000", "000001", "000002"]


def test_holdout_directory_still_a_directory(tiny_session):
    train, held = hold_out(list(iter_frames(tiny_session / "s")), str(tiny_session / "s"), "--holdout", 0.3)
    assert len(held) == 4 and train == []


@pytest.fixture(scope="module")
def six_sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("split")
    for i in range(6):
        write_session(root / f"s{i}", 1, 20 + i, SceneConfig(**TINY))
    return root


def test_test_sessions_are_set_aside_before_the_folds_and_no_frame_has_two_roles(six_sessions):
    split = plan(six_sessions, "auto", "auto", "auto", ("reference",))
    roles = split.roles()
    assert roles["test"] == ["s4/000000", "s5/000000"]              # the last quarter of the sessions
    assert split.k == 3                                              # the four left: 3 folds
    assert len(roles["train"]) == 4 and sorted(roles["validation"]) == sorted(roles["train"])
    assert not set(roles["test"]) & set(roles["train"])
    assert split.notes == ()                                         # whole sessions: nothing correlated


def test_explicit_test_and_holdout_and_their_errors(six_sessions):
    split = plan(six_sessions, "s0,s1", "s2", "1", ())
    assert split.roles() == {"train": ["s3/000000", "s4/000000", "s5/000000"], "validation": ["s2/000000"],
                             "test": ["s0/000000", "s1/000000"]}
    # a frame the test already holds cannot be asked for again as a validation frame
    with pytest.raises(ConfigError, match="--holdout must name sessions"):
        plan(six_sessions, "s0", "s0", "1", ())
    with pytest.raises(ConfigError, match="--test must be a fraction between 0 and 1"):
        plan(six_sessions, "1.5", "auto", "auto", ())
    none = plan(six_sessions, "auto", "none", "auto", ())            # --holdout none: no test either
    assert none.k == 1 and not len(none.test) and any("no test frame" in n for n in none.notes)
