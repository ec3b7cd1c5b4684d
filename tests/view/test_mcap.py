"""MCAP recordings of the view (``demo --mcap``, ``replay --mcap``), read back with the ``mcap`` reader."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("mcap")

from companion.offline.harness import LOCKSTEP_EPOCH_S, run_lockstep  # noqa: E402
from companion.offline.replay import replay  # noqa: E402
from companion.view.channels import TOPICS  # noqa: E402
from companion.view.publisher import ViewPublisher  # noqa: E402
from tests.support.foxglove_decode import read_mcap  # noqa: E402
from tests.px4.sitl import REPO  # noqa: E402

SCENARIO = REPO / "configs" / "antipodal.toml"


@pytest.fixture(scope="module")
def antipodal(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap")
    view = ViewPublisher(mcap=out / "antipodal.mcap", time_offset_s=LOCKSTEP_EPOCH_S)
    with view:
        result = run_lockstep(SCENARIO, tlog_path=out / "companion.tlog", after_tick=view)
    return out, result, view, read_mcap(out / "antipodal.mcap")


def _positions(scene: dict) -> np.ndarray:
    (entity,) = scene["entities"]
    return np.array([[p.get(k, 0.0) for k in "xyz"] for p in entity["lines"][0]["points"]])


def test_every_channel_with_its_schema_and_one_message_per_tick_or_replan(antipodal):
    out, result, view, topics = antipodal
    assert set(topics) == set(TOPICS)
    for topic, (_, schema) in TOPICS.items():
        assert {name for _, name, _ in topics[topic]} == {schema}, topic
    ticks = int(round(result.sim_time_s * result.companion.settings.setpoint_rate_hz))
    replans = len(result.companion.records)
    assert view.ticks == ticks == len(topics["/loop"]) == len(topics["/tracks"])
    assert replans > 20
    assert len(topics["/plan"]) == len(topics["/plan/summary"]) == len(topics["/contour"]) == replans
    # the setpoints sent: one per streaming tick, the same numbers as the companion's records' commands
    assert 0 < len(topics["/setpoint"]) <= ticks
    assert len(topics["/vehicle/pose"]) == len(topics["/vehicle/ellipsoid"]) >= ticks - 20
    stamps = [t for t, _, _ in topics["/loop"]]
    assert stamps == sorted(stamps) and stamps[0] >= LOCKSTEP_EPOCH_S * 1e9


def test_the_plans_positions_are_the_records(antipodal):
    out, result, view, topics = antipodal
    records = result.companion.records
    for rec, (_, _, scene), (_, _, summary) in zip(records, topics["/plan"], topics["/plan/summary"]):
        np.testing.assert_array_equal(np.array(summary["positions"]), rec.plan_positions)
        np.testing.assert_allclose(_positions(scene), rec.plan_positions, rtol=0, atol=1e-12)
        assert summary["status"] == rec.status.value
        entity = scene["entities"][0]
        assert len(entity["spheres"]) == len(rec.plan_positions)     # the horizon's ellipsoids
    contours = [c for _, _, c in topics["/contour"]]
    realised = [c["min_realised"] for c in contours if c["min_realised"] is not None]
    assert realised and min(realised) == pytest.approx(result.companion.state.min_realised_contour)


def test_tracks_carry_ellipsoids_and_ids(antipodal):
    out, result, view, topics = antipodal
    ids = {e["id"] for _, _, scene in topics["/tracks"] for e in scene.get("entities", [])}
    assert ids and all(i.startswith("track/") for i in ids)
    _, _, last = topics["/tracks"][-1]
    for entity in last["entities"]:
        key = entity["id"].removeprefix("track/")
        assert entity["texts"][0]["text"] == key
        size = entity["spheres"][0]["size"]
        assert all(size.get(k, 0.0) > 0.0 for k in "xyz")


def test_replay_writes_the_same_plans_from_the_tlog(antipodal, tmp_path):
    out, result, _, topics = antipodal
    view = ViewPublisher(mcap=tmp_path / "replay.mcap", time_offset_s=LOCKSTEP_EPOCH_S)
    with view:
        replayed = replay(out / "companion.tlog", SCENARIO, after_tick=view)
    assert replayed.summary()["max_abs_diff_mps"] == 0.0
    again = read_mcap(tmp_path / "replay.mcap")
    assert set(again) == set(TOPICS)
    assert [m["positions"] for _, _, m in again["/plan/summary"]] == [m["positions"] for _, _, m in topics["/plan/summary"]]


def test_replay_takes_mcap_on_the_command_line(antipodal, tmp_path):
    out = antipodal[0]
    cmd = [sys.executable, "-m", "companion.cli", "replay", str(out / "companion.tlog"), "--scenario", "antipodal",
           "--mcap", str(tmp_path / "r.mcap"), "--json"]
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=300)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["view"]["view_channels"]["/plan"] == summary["replans"]
    assert (tmp_path / "r.mcap").stat().st_size > 10_000


def test_without_the_view_extra_mcap_is_one_line_and_exit_2(tmp_path):
    code = ("import sys, builtins; real = builtins.__import__\n"
            "def imp(name, *a, **k):\n"
            "    if name.startswith('foxglove'): raise ImportError(name)\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = imp\n"
            "from companion.cli import main; sys.exit(main(['demo', 'single_obstacle', '--mcap', sys.argv[1]]))\n")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "x.mcap")], capture_output=True, text=True,
                         cwd=REPO, timeout=120)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().count("\n") == 0 and "view extra" in out.stderr, out.stderr


def test_the_shipped_layout_names_only_the_views_channels():
    import re

    layout = json.loads((REPO / "docs" / "foxglove_layout.json").read_text())
    text = json.dumps(layout["configById"])
    named = set(re.findall(r'"(/[a-z/]+)', text))
    assert named and named <= set(TOPICS), named - set(TOPICS)


def test_the_map_draws_each_wall_as_a_plate_across_its_normal():
    from companion.loop.config import load_scenario
    from companion.view.channels import MessageBuilder
    from companion.view.snapshot import TickSnapshot
    from tests.support.foxglove_decode import decoder

    scenario = load_scenario(REPO / "configs" / "corridor.toml")
    snap = TickSnapshot(t_s=0.0, t_vehicle_s=None, mode="waiting", drone=None, tracks=(), setpoint=None, replans=(),
                        scenario=scenario)
    (scene,) = [m for topic, m in MessageBuilder().messages(snap) if topic == "/map"]
    schema = scene.get_schema()
    (entity,) = decoder(schema.name, schema.encoding, schema.data)(scene.encode())["entities"]
    assert len(entity["cubes"]) == len(scenario.walls) > 0
    for wall, cube in zip(scenario.walls, entity["cubes"]):
        q = cube["pose"]["orientation"]
        x, y, z, w = (q.get(k, 0.0) for k in "xyzw")
        z_axis = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])   # R e_z
        np.testing.assert_allclose(z_axis, np.asarray(wall.normal) / np.linalg.norm(wall.normal), atol=1e-9)
        p = cube["pose"]["position"]
        assert np.dot([p.get(k, 0.0) for k in "xyz"], wall.normal) == pytest.approx(wall.offset)
