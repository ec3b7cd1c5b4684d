"""Keep right, and get out of a standoff (companion/loop/right_of_way.py)."""

import numpy as np
import pytest

from companion.loop.right_of_way import ProgressWatch, RightOfWay, keep_right, meets, right_of

Z = -5.0


def test_that_right_is_east_of_north_and_south_of_east():
    assert np.allclose(right_of(np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0])
    assert np.allclose(right_of(np.array([0.0, 2.0, 0.5])), [-1.0, 0.0, 0.0])
    assert np.allclose(right_of(np.zeros(3)), 0.0)


def test_that_a_peer_is_met_only_ahead_closing_and_passing_within_reach_inside_the_horizon():
    here, v = np.array([0.0, 0.0, Z]), np.array([1.0, 0.0, 0.0])
    north = np.array([1.0, 0.0, 0.0])
    head_on = (np.array([10.0, 0.3, Z]), np.array([-1.0, 0.0, 0.0]))
    assert meets(here, v, *head_on, north, reach_m=1.5, horizon_s=6.0)
    assert not meets(here, v, *head_on, north, reach_m=1.5, horizon_s=4.0)          # meets at 5 s
    assert not meets(here, v, np.array([10.0, 3.0, Z]), np.array([-1.0, 0.0, 0.0]), north, 1.5, 6.0)  # passes 3 m off
    assert not meets(here, v, np.array([-5.0, 0.0, Z]), np.array([2.0, 0.0, 0.0]), north, 1.5, 6.0)   # behind
    assert not meets(here, v, np.array([5.0, 0.0, Z]), np.array([3.0, 0.0, 0.0]), north, 1.5, 6.0)    # pulling away
    assert meets(here, v, np.array([1.0, 0.5, Z]), np.array([1.0, 0.0, 0.0]), north, 1.5, 6.0)        # ahead, within reach


def test_that_two_drones_meeting_head_on_move_to_opposite_sides_and_pass_left_to_left():
    a, b = np.array([-6.0, 0.0, Z]), np.array([6.0, 0.0, Z])
    va, vb = np.array([1.5, 0.0, 0.0]), np.array([-1.5, 0.0, 0.0])
    ta, met_a = keep_right(a, va, b, [(b, vb, 1.6)], horizon_s=6.0)
    tb, met_b = keep_right(b, vb, a, [(a, va, 1.6)], horizon_s=6.0)
    assert met_a == met_b == 1
    assert ta[1] == pytest.approx(1.6) and tb[1] == pytest.approx(-1.6)   # a goes east, b west: they pass port to port
    same, met = keep_right(a, va, b, [(np.array([6.0, 4.0, Z]), vb, 1.6)], horizon_s=6.0)
    assert met == 0 and np.allclose(same, b)


def test_that_a_standoff_is_detected_after_the_configured_time_counted_and_recovered_from():
    watch = ProgressWatch(after_s=6.0, progress_m=0.5, recovery_s=4.0)
    t = np.arange(0.0, 20.0, 0.3)
    flags = [watch.update(ti, 10.0 - 0.01 * ti, peer_near=True) for ti in t]
    first = t[flags.index(True)]
    assert first == pytest.approx(6.0, abs=0.31)
    assert all(f for ti, f in zip(t, flags) if first <= ti < first + 4.0)    # recovering
    assert watch.deadlocks == 2 and len(watch.detected_t_s) == 2              # and again after 6 s more
    moving = ProgressWatch(after_s=6.0, progress_m=0.5, recovery_s=4.0)
    assert not any(moving.update(ti, 10.0 - 0.5 * ti, True) for ti in t)     # progress: no deadlock
    alone = ProgressWatch(after_s=6.0, progress_m=0.5, recovery_s=4.0)
    assert not any(alone.update(ti, 10.0, False) for ti in t)                # stuck, but no peer near: not this rule's


def test_that_right_of_way_moves_the_target_wider_while_recovering():
    row = RightOfWay(6.0, after_s=3.0, progress_m=0.5, recovery_s=2.0)
    here, goal = np.array([0.0, 0.0, Z]), np.array([10.0, 0.0, Z])
    peer = [(np.array([1.2, 0.2, Z]), np.zeros(3), 1.5)]                       # standing in the way, within reach
    targets = [row.target(t, here, np.zeros(3), goal, goal, peer) for t in np.arange(0.0, 4.0, 0.3)]
    assert targets[0][1] == pytest.approx(1.5)
    assert max(tg[1] for tg in targets) == pytest.approx(3.0)
    assert row.summary()["deadlocks"] == 1 and row.summary()["kept_right"] == len(targets)
