"""One piece of work at a time in a node, and an accepted goal that never executes (its response lost) does not
leave the node busy for ever."""
from __future__ import annotations

import time

import pytest

from cito_ros.ros.goal_slot import GoalSlot


def test_an_accepted_goal_holds_the_slot_until_its_work_ends():
    slot = GoalSlot()
    assert slot.accept()
    assert not slot.accept() and not slot.take()  # accepted, not yet begun: a second goal or call is busy
    assert slot.begin() and slot.running
    assert not slot.accept() and not slot.take()
    slot.end()
    assert not slot.running and slot.take()
    assert not slot.accept()
    slot.end()
    assert slot.accept()


def test_a_goal_accepted_but_never_begun_lets_its_claim_lapse():
    slot = GoalSlot(lapse_s=0.05)
    assert slot.accept()  # its acceptance lost on the way: no execute callback follows
    assert not slot.accept()
    time.sleep(0.06)
    assert slot.accept() and slot.begin()


def test_a_lapsed_goal_that_begins_late_beside_running_work_is_refused():
    slot = GoalSlot(lapse_s=0.05)
    assert slot.accept()
    time.sleep(0.06)
    assert slot.accept() and slot.begin()
    assert not slot.begin()  # the first goal's execute callback, late: the node ends it as busy


def test_a_lapse_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match="lapse_s must be positive"):
        GoalSlot(lapse_s=0.0)
