"""A signed flight: mavsim and ``companion fly`` in real time over loopback UDP, both signing (issue 14).

Each side rejects unsigned and badly signed packets, so engaging OFFBOARD and reaching the
goal needs both to sign with the same key; neither counts a rejected packet. About 20 s.
"""

from __future__ import annotations

import json

from companion.cli import main

KEY_HEX = "5a" * 32


def test_that_a_signed_flight_over_udp_reaches_the_goal_with_nothing_rejected(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("OGCC_TEST_SIGNING_KEY", KEY_HEX)
    out = tmp_path / "run"
    assert main(["demo", "tests/data/short_hop.toml", "--realtime", "--json", "--out", str(out),
                 "--signing-key-env", "OGCC_TEST_SIGNING_KEY"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["signing"] is True and summary["signature_rejected"] == 0, summary
    assert any("ENGAGED" in text for _, text in summary["events"]), summary.get("events")
    assert summary["goal_reached"] is True and summary["collided"] is False
    truth = json.loads((out / "truth.json").read_text())
    assert truth["link"].get("signature_rejected", 0) == 0 and truth["link"]["packets_received"] > 50
    # every packet mavsim sent on the API link was signed (MAVLink 2, incompat flag 0x01)
    data = (out / "mavsim.tlog").read_bytes()
    first_packet = data[8:]
    assert first_packet[0] == 0xFD and first_packet[2] & 0x01
