"""Daemon test fixtures."""

import pytest

from mavlink_peer import Receiver


@pytest.fixture
def rx():
    """A real pymavlink endpoint on loopback, standing in for the flight controller."""
    r = Receiver()
    yield r
    r.close()
