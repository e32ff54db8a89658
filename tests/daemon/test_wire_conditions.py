"""docs/wire.md's table, row by row, through the real daemon process and a real pymavlink peer.

For every :class:`Condition` of the contract, a scenario (tests/wire_scenarios.py) drives
``uav-depth run`` into it from outside, and what the peer received in that condition must be
the row: a DISTANCE_SENSOR with the row's fields or none, the HEARTBEAT state and the
STATUSTEXT the row names (read from ``Condition``, the source of the table). Each scenario
runs once for the conditions it covers; the windows are bounded by what arrived, so the
tests hold on a loaded machine.
"""

from __future__ import annotations

import pytest

from wire_rows import judge
from wire_scenarios import SCENARIO_OF, SCENARIOS

from uav_depth.daemon.link.conditions import Condition


def test_every_condition_of_the_contract_has_a_scenario():
    assert set(SCENARIO_OF) == set(Condition)
    assert sum(len(s.conditions) for s in SCENARIOS) == len(Condition)


@pytest.fixture(scope="module")
def observed(tmp_path_factory):
    """The windows of a scenario, run at most once (a failure is kept and raised for each of its conditions)."""
    runs: dict[str, object] = {}

    def of(scenario):
        if scenario.name not in runs:
            try:
                runs[scenario.name] = scenario.run(tmp_path_factory.mktemp(scenario.name))
            except AssertionError as exc:
                runs[scenario.name] = exc
        got = runs[scenario.name]
        if isinstance(got, AssertionError):
            raise got
        return got
    return of


@pytest.mark.timeout(600)
@pytest.mark.parametrize("cond", list(Condition), ids=lambda c: c.value.replace(" ", "-"))
def test_what_the_peer_receives_in_each_condition_is_its_row(observed, cond):
    scenario = SCENARIO_OF[cond]
    row = judge(cond, observed(scenario)[cond])
    assert row.ok, f"{scenario.name}: expected {row.expected}; observed {row.observed}"
