"""The live view: a Foxglove WebSocket client (Foxglove's ws-protocol: ``foxglove.websocket.v1``, which the SDK names ``foxglove.sdk.v1``) during a lockstep demo.

The client here is a few lines of the protocol over the ``websockets`` package: it reads the
server's ``advertise``, subscribes to every channel, and decodes the binary ``message data``
frames (opcode 1, subscription id, log time, payload) by the advertised schema.
"""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import threading

import numpy as np
import pytest

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

from companion.offline.harness import LOCKSTEP_EPOCH_S, run_lockstep  # noqa: E402
from companion.view.channels import TOPICS  # noqa: E402
from companion.view.publisher import ViewPublisher  # noqa: E402
from tests.support.foxglove_decode import decoder  # noqa: E402
from tests.px4.sitl import REPO  # noqa: E402

SCENARIO = REPO / "configs" / "antipodal.toml"
#: The ws-protocol's subprotocol, and the name the Foxglove SDK (0.30) accepts it under.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


class Client:
    """Connects, subscribes to every advertised channel and collects decoded messages per topic."""

    def __init__(self, port: int) -> None:
        self.url = f"ws://127.0.0.1:{port}"
        self.ready = threading.Event()
        self.stop = threading.Event()
        self.channels: dict[int, dict] = {}
        self.received: dict[str, list] = {}
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _connect(self):
        """Connect, retrying while the server is not up yet (a process still starting) until stopped."""
        while True:
            try:
                return await websockets.connect(self.url, subprotocols=SUBPROTOCOLS, max_size=None)
            except OSError:
                if self.stop.is_set():
                    raise
                await asyncio.sleep(0.2)

    async def _main(self) -> None:
        try:
            async with await self._connect() as ws:
                assert ws.subprotocol in SUBPROTOCOLS
                subs: dict[int, tuple[str, object]] = {}
                while not self.stop.is_set():
                    try:
                        frame = await asyncio.wait_for(ws.recv(), timeout=0.2)
                    except asyncio.TimeoutError:
                        continue
                    if isinstance(frame, str):
                        msg = json.loads(frame)
                        if msg.get("op") == "advertise":
                            new = []
                            for ch in msg["channels"]:
                                self.channels[ch["id"]] = ch
                                sub_id = len(subs) + 1
                                schema = ch["schema"]
                                data = base64.b64decode(schema) if ch.get("schemaEncoding") == "protobuf" else schema.encode()
                                subs[sub_id] = (ch["topic"], decoder(ch["schemaName"], ch.get("schemaEncoding", ""), data))
                                new.append({"id": sub_id, "channelId": ch["id"]})
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                            if {c["topic"] for c in self.channels.values()} >= set(TOPICS):
                                self.ready.set()
                    elif frame[0] == 0x01:                               # message data
                        sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                        topic, decode = subs[sub_id]
                        self.received.setdefault(topic, []).append((log_time, decode(frame[13:])))
        except BaseException as exc:  # reported by the test
            self.error = exc
            self.ready.set()


def test_a_foxglove_client_sees_plan_and_tracks_with_their_schemas_during_a_lockstep_demo():
    view = ViewPublisher(server=("127.0.0.1", 0), time_offset_s=LOCKSTEP_EPOCH_S)
    try:
        client = Client(view.port)
        client.thread.start()
        assert client.ready.wait(20.0) and client.error is None, client.error
        schemas = {ch["topic"]: ch["schemaName"] for ch in client.channels.values()}
        assert schemas == {topic: schema for topic, (_, schema) in TOPICS.items()}
        encodings = {ch["topic"]: ch["encoding"] for ch in client.channels.values()}
        assert encodings["/plan"] == encodings["/tracks"] == "protobuf" and encodings["/plan/summary"] == "json"
        import time

        time.sleep(0.5)   # the subscriptions reach the server before the first tick
        result = run_lockstep(SCENARIO, after_tick=view)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and len(client.received.get("/plan/summary", [])) < len(result.companion.records):
            time.sleep(0.1)
    finally:
        client.stop.set()
        client.thread.join(5.0)
        view.close()
    assert client.error is None, client.error
    got = client.received
    assert {"/plan", "/plan/summary", "/tracks", "/vehicle/pose", "/setpoint", "/contour"} <= set(got)
    records = {rec.t_link_s: rec for rec in result.companion.records}
    # every plan that arrived is the companion's, in its positions (summary and LinePrimitive alike)
    assert len(got["/plan/summary"]) >= len(records) // 2
    for (t_ns, summary), (_, scene) in zip(got["/plan/summary"], got["/plan"]):
        rec = records[summary["t_s"]]
        np.testing.assert_array_equal(np.array(summary["positions"]), rec.plan_positions)
        points = scene["entities"][0]["lines"][0]["points"]
        np.testing.assert_allclose([[p.get(k, 0.0) for k in "xyz"] for p in points], rec.plan_positions, atol=1e-12)
        assert t_ns == int(round((rec.t_applied_s + LOCKSTEP_EPOCH_S) * 1e9))
    # the tracks: an ellipsoid and an id each, one entity per obstacle of the scenario
    from companion.view.snapshot import _track_name

    ids = {e["id"] for _, scene in got["/tracks"] for e in scene.get("entities", [])}
    assert ids == {f"track/{_track_name(k)}" for k in result.companion.tracker.keys()}
    for _, scene in got["/tracks"][-3:]:
        for entity in scene["entities"]:
            assert entity["texts"][0]["text"] == entity["id"].removeprefix("track/")
            assert all(entity["spheres"][0]["size"].get(k, 0.0) > 0.0 for k in "xyz")
