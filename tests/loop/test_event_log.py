"""The loop's events in bounded memory (companion.loop.records.EventLog)."""

from __future__ import annotations

import tracemalloc

from companion.loop.records import EventLog
from companion.loop.supervisor import Supervisor


def test_that_the_first_and_the_latest_are_kept_and_the_rest_counted():
    log = EventLog(head=3, tail=4)
    for i in range(20):
        log.append((float(i), f"e{i}"))
    assert [text for _, text in log] == ["e0", "e1", "e2", "e16", "e17", "e18", "e19"]
    assert log.total == 20 and len(log) == 7 and log.dropped == 13
    assert log[-1] == (19.0, "e19") and log[0] == (0.0, "e0")
    assert log == [(float(i), f"e{i}") for i in (0, 1, 2, 16, 17, 18, 19)]


def test_that_a_short_run_keeps_every_event_as_a_list_would():
    log = EventLog()
    assert not log and len(log) == 0
    for i in range(10):
        log.append((float(i), str(i)))
    assert log and log.dropped == 0 and list(log) == [(float(i), str(i)) for i in range(10)] and log[-1] == (9.0, "9")


def test_that_an_hour_of_slack_announcements_takes_bounded_memory():
    supervisor = Supervisor(0.0)

    def say(first: int, count: int) -> None:
        for k in range(first, first + count):
            supervisor.say(k * 0.3, 4, f"companion: safety slack used (0.12) #{k}")

    tracemalloc.start()
    try:
        say(0, 12_000)                                               # an hour at 3.3 a second: head and tail full
        after_one_hour, _ = tracemalloc.get_traced_memory()
        say(12_000, 24_000)                                          # two hours more
        after_three, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after_three - after_one_hour < 10_000, (after_one_hour, after_three)   # a list: about 4 MB more
    assert supervisor.events.total == 36_000 and len(supervisor.events) == 2000
