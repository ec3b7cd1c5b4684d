"""The stream's garbage-collector guard: startup objects frozen for the run, pauses measured, all undone after."""

from __future__ import annotations

import gc

from companion.realtime.collector import collector_for_real_time


def test_that_objects_existing_at_the_start_are_frozen_for_the_block_and_released_after():
    before = [[i] for i in range(1000)]  # containers the collector would otherwise walk
    assert gc.get_freeze_count() == 0
    with collector_for_real_time():
        assert gc.get_freeze_count() >= len(before)
    assert gc.get_freeze_count() == 0


def test_that_every_collection_inside_the_block_is_counted_and_its_pause_measured():
    with collector_for_real_time() as pauses:
        gc.collect()
        gc.collect(0)
    assert pauses.collections >= 2
    assert 0.0 < pauses.max_pause_s < 10.0


def test_that_the_callback_is_removed_even_when_the_block_raises():
    callbacks = list(gc.callbacks)
    try:
        with collector_for_real_time():
            raise RuntimeError("stream ended badly")
    except RuntimeError:
        pass
    assert gc.callbacks == callbacks and gc.get_freeze_count() == 0
