"""``demo antipodal --realtime --view`` with a Foxglove client connected: the stream keeps its 20 Hz."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from tests.px4.sitl import REPO  # noqa: E402
from tests.view.test_live import Client  # noqa: E402

pytestmark = [pytest.mark.realtime]


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_realtime_demo_with_a_client_on_the_view_keeps_20_hz_without_a_gap_over_150_ms(tmp_path):
    port = _free_tcp_port()
    demo = subprocess.Popen([sys.executable, "-m", "companion.cli", "demo", "antipodal", "--realtime",
                             "--view", f"127.0.0.1:{port}", "--mcap", str(tmp_path / "live.mcap"), "--json"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = Client(port)
    client.thread.start()
    try:
        assert client.ready.wait(90.0) and client.error is None, client.error
        out, err = demo.communicate(timeout=240)
    finally:
        client.stop.set()
        client.thread.join(5.0)
        if demo.poll() is None:
            demo.kill()
    summary = json.loads(out)
    view = summary["view"]
    print(json.dumps({k: summary.get(k) for k in ("setpoint_rate_hz", "setpoint_gap_max_ms", "setpoint_gaps_over_150ms",
                                                  "tick_max_ms", "stream_cpu_share", "collided")}, indent=1))
    print(json.dumps(view, indent=1))
    print({topic: len(msgs) for topic, msgs in client.received.items()})
    assert summary.get("collided") is False, summary
    assert summary["setpoint_rate_hz"] == pytest.approx(20.0, abs=0.5)
    assert summary["setpoint_gaps_over_150ms"] == 0 and summary["setpoint_gap_max_ms"] < 150
    assert view["view_cpu_share"] is not None and view["view_dropped"] == 0
    assert len(client.received.get("/loop", [])) > 0.8 * view["view_ticks"]
    assert len(client.received.get("/plan/summary", [])) > 10
