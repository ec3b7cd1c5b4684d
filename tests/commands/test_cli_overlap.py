"""``companion overlap`` and ``companion overlap-table`` through ``companion.cli.main``."""

from __future__ import annotations

import json

import pytest

from companion.cli import main


def test_that_overlap_prints_the_touch_radius_and_overlap_of_the_reference_row(capsys):
    assert main(["overlap", "--dim", "3", "--confidence", "0.6"]) == 0
    out = capsys.readouterr().out
    assert "1.7164" in out and "0.0861" in out


def test_that_overlap_json_is_one_object_and_the_inverse_round_trips(capsys):
    assert main(["overlap", "--dim", "2", "--confidence", "0.8051", "--json"]) == 0
    forward = json.loads(capsys.readouterr().out)
    assert forward["touch_radius"] == pytest.approx(1.8085, abs=5e-5)
    assert forward["overlap"] == pytest.approx(0.0705, abs=5e-5)
    assert main(["overlap", "--dim", "2", "--overlap", str(forward["overlap"]), "--json"]) == 0
    inverse = json.loads(capsys.readouterr().out)
    assert inverse["confidence"] == pytest.approx(0.8051, rel=1e-10)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["overlap", "--dim", "3", "--confidence", "1.2"], "must lie in the open interval (0, 1)"),
        (["overlap", "--dim", "3", "--confidence", "abc"], "not a number"),
        (["overlap", "--dim", "0", "--confidence", "0.5"], "must be >= 1"),
        (["overlap", "--dim", "3"], "one of the arguments --confidence --overlap is required"),
        (["overlap", "--confidence", "0.5", "--overlap", "0.1"], "not allowed with argument"),
    ],
)
def test_that_a_bad_value_exits_2_with_a_clear_message(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_that_the_table_lists_every_reference_row_and_the_bhattacharyya_demo(capsys):
    assert main(["overlap-table"]) == 0
    out = capsys.readouterr().out
    lines = {line.split()[0]: line.split()[1:] for line in out.splitlines() if line.strip()[:1].isdigit()}
    assert lines["0.8051"][:2] == ["1.8085", "0.0705"]  # 2-D
    assert lines["0.9000"] == ["2.1460", "0.0319", "2.5003", "0.0124"]
    assert lines["0.6000"][2:] == ["1.7164", "0.0861"]  # 3-D
    assert lines["0.3000"][2:] == ["1.1932", "0.2328"]
    assert "Bhattacharyya 1.6079" in out and "Bhattacharyya 1.7108" in out
    assert out.count("overlap 0.0705") == 2


def test_that_the_table_plot_writes_a_png(tmp_path, capsys):
    target = tmp_path / "figs" / "overlap.png"
    assert main(["overlap-table", "--plot", str(target)]) == 0
    assert str(target) in capsys.readouterr().out
    data = target.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert 10_000 < len(data) < 2_000_000
