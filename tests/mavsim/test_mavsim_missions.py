"""mavsim speaks the mission protocol: the companion's upload and download machines against it, round trip."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.mission_protocol import FENCE, MissionDownload, MissionItem, MissionUpload
from tests.support.mavsim_client import AIRBORNE, Client

AP = (1, 1)


def _transfer(c: Client, machine, until_s: float = 10.0) -> None:
    for msg in machine.start(c.sim.time_s):
        c.send(msg)
    t_end = c.sim.time_s + until_s
    while not machine.over and c.sim.time_s < t_end:
        for m in c.run(0.05):
            for answer in machine.on_message(c.sim.time_s, m):
                c.send(answer)
        for msg in machine.step(c.sim.time_s):
            c.send(msg)


def _items(n, frame=3, command=16):
    return [MissionItem(seq=i, frame=frame, command=command, params=(0.0, 1.0, 0.0, 0.0),
                        x=47.3978 + i * 1e-4, y=8.5456, z=5.0 + i) for i in range(n)]


def test_that_an_uploaded_mission_and_fence_come_back_as_sent():
    c = Client(AIRBORNE)
    up = MissionUpload(AP, _items(5))
    _transfer(c, up)
    assert up.done and up.resent == 0
    fence = MissionUpload(AP, _items(4, frame=5, command=5001), mission_type=FENCE)
    _transfer(c, fence)
    assert fence.done
    down = MissionDownload(AP)
    _transfer(c, down)
    assert down.done and [(i.seq, i.command, round(i.x, 7), i.z) for i in down.items] == \
        [(i.seq, i.command, round(i.x, 7), i.z) for i in _items(5)]
    fence_down = MissionDownload(AP, FENCE)
    _transfer(c, fence_down)
    assert [i.command for i in fence_down.items] == [5001] * 4
    c.send(mavlink2.MAVLink_mission_set_current_message(1, 1, 3))
    current = [m for m in c.run(0.1) if m.get_type() == "MISSION_CURRENT"]
    assert current and current[-1].seq == 3 and current[-1].total == 5


def test_that_an_item_in_a_local_frame_is_refused_by_name():
    c = Client(AIRBORNE)
    up = MissionUpload(AP, _items(2, frame=1))
    _transfer(c, up)
    assert up.failed == "mission upload failed: the vehicle answered MAV_MISSION_UNSUPPORTED_FRAME"
