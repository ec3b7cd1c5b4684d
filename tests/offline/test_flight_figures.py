"""Flight figures: produced from demo and replay runs, robust to empty runs; the ellipse is the c_min slice."""

import numpy as np
import pytest

from companion.loop.app import Companion
from companion.cli import main
from companion.offline.harness import run_lockstep
from companion.core.overlap import touch_radius
from companion.plots.ellipses import slice_ellipse, top_view_ellipse
from companion.plots.flight_figures import write_flight_figures
from companion.loop.config import load_scenario

SCENARIO = "configs/antipodal.toml"
NAMES = ["topview.png", "contour.png", "speed_accel.png", "solve_time.png"]
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = tmp_path_factory.mktemp("figs") / "run.tlog"
    return run_lockstep(SCENARIO, seed=0, tlog_path=path, duration_s=12)


def _check(paths, out_dir, min_bytes=10_000):
    for p in paths:
        assert p.parent == out_dir and p.exists()
        data = p.read_bytes()
        assert data[:8] == PNG
        assert min_bytes < len(data) < 400_000, (p.name, len(data))


def test_that_a_demo_run_gives_four_plausible_pngs(run, tmp_path):
    paths = write_flight_figures(run.companion, tmp_path / "out", truth=run.truth)
    assert [p.name for p in paths] == NAMES
    _check(paths, tmp_path / "out")


def test_that_a_prefix_names_the_files(run, tmp_path):
    paths = write_flight_figures(run.companion, tmp_path, prefix="antipodal_")
    assert [p.name for p in paths] == ["antipodal_" + n for n in NAMES]


def test_that_replay_plot_writes_the_same_figures(run, tmp_path, capsys):
    assert main(["replay", str(run.tlog_path), "--scenario", SCENARIO, "--plot", str(tmp_path / "plots")]) == 0
    assert "figure: " in capsys.readouterr().out
    _check([tmp_path / "plots" / n for n in NAMES], tmp_path / "plots")


@pytest.mark.parametrize("config", ["configs/antipodal.toml", "configs/corridor.toml"])
def test_that_a_run_without_replans_or_obstacles_still_gives_figures(tmp_path, config):
    companion = Companion(load_scenario(config))  # never ticked: no records, no tracks
    paths = write_flight_figures(companion, tmp_path, truth=None)
    assert [p.name for p in paths] == NAMES
    assert all(p.exists() and p.stat().st_size > 1000 for p in paths)


def test_that_the_ellipse_of_a_diagonal_covariance_has_sigma_times_the_touch_radius():
    cov = np.diag([0.04, 0.01, 0.09])  # sigma north 0.2, east 0.1, down 0.3
    w, h, angle = slice_ellipse(cov, 0.9)
    r = touch_radius(0.9, 3)
    axes = {round(w, 12), round(h, 12)}
    assert axes == {round(2 * r * 0.1, 12), round(2 * r * 0.2, 12)}
    # the longer axis points north (vertical in the plot: angle 90 deg modulo 180)
    long_angle = angle if w > h else angle + 90.0
    assert np.isclose(np.cos(np.radians(long_angle)), 0.0, atol=1e-9)


def test_that_the_ellipse_is_the_horizontal_slice_of_the_correlated_ellipsoid():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    c = 0.9
    w, h, angle = slice_ellipse(cov, c)
    r = touch_radius(c, 3)
    inv = np.linalg.inv(cov)
    th = np.radians(angle)
    for s in np.linspace(0, 2 * np.pi, 17):
        east = 0.5 * w * np.cos(s) * np.cos(th) - 0.5 * h * np.sin(s) * np.sin(th)
        north = 0.5 * w * np.cos(s) * np.sin(th) + 0.5 * h * np.sin(s) * np.cos(th)
        d = np.array([north, east, 0.0])  # NED offset on the boundary, in the horizontal plane
        assert d @ inv @ d == pytest.approx(r**2, rel=1e-9)


def test_that_the_shadow_ellipse_is_the_projection_of_the_correlated_ellipsoid():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    r = touch_radius(0.9, 3)
    w, h, angle = top_view_ellipse(cov, 0.9, view="shadow")
    th = np.radians(angle)
    for s in np.linspace(0, 2 * np.pi, 13):
        # boundary point of the drawn ellipse and its outward normal, in (north, east)
        east = 0.5 * w * np.cos(s) * np.cos(th) - 0.5 * h * np.sin(s) * np.sin(th)
        north = 0.5 * w * np.cos(s) * np.sin(th) + 0.5 * h * np.sin(s) * np.cos(th)
        n_ne = np.linalg.solve(cov[:2, :2], [north, east])
        n = np.array([n_ne[0], n_ne[1], 0.0]) / np.linalg.norm(n_ne)
        # the 3-D ellipsoid's support along a horizontal normal is r sqrt(n' S n): the shadow's edge
        assert n[:2] @ [north, east] == pytest.approx(r * np.sqrt(n @ cov @ n), rel=1e-9)
    ws, hs, _ = top_view_ellipse(cov, 0.9, view="slice")
    assert ws * hs < w * h  # the slice lies inside the shadow
    with pytest.raises(ValueError, match="view must be one of"):
        top_view_ellipse(cov, 0.9, view="side")


def test_that_legends_name_tracks_as_people_say_them():
    from companion.plots.flight_figures import _track_label

    assert _track_label((101, 197, "obstacles1")) == "system 101 on obstacles1"
    assert _track_label(("icao", 0x4CA2B1)) == "ICAO 4CA2B1"
    assert _track_label((42, 1)) == "system 42"
    assert _track_label(("uas", b"AB\x00", "obstacles2")) == "Remote ID 4142 on obstacles2"


def test_that_the_contour_figure_draws_each_track_apart_with_its_name_against_run_time(run):
    """The contour plot stacked every obstacle at 1.00, legends were Python tuples and the axes
    Unix epoch seconds: now one clearance line per track, named, over seconds since the start."""
    import matplotlib.pyplot as plt

    from companion.plots.flight_figures import _contour

    fig = _contour(run.companion, list(run.companion.records), run.truth)
    try:
        ax_clearance, ax_contour = fig.axes[:2]
        lines = [line for line in ax_clearance.get_lines() if not line.get_label().startswith("_")]
        labels = [line.get_label() for line in lines]
        assert len(labels) == len(set(labels)) >= 2, labels               # one line per track
        assert all(label.startswith("system ") and "(" not in label for label in labels), labels
        finals = [float(line.get_ydata()[-1]) for line in lines]
        assert len({round(v, 2) for v in finals}) == len(finals), finals   # not stacked on one value
        t_end = max(float(np.max(line.get_xdata())) for line in lines)
        assert 0.0 <= min(float(np.min(line.get_xdata())) for line in lines) and t_end < 60.0  # not epoch seconds
        assert ax_contour.get_xlabel() == "time since the run's start [s]"
        assert [t.get_text() for t in ax_clearance.get_legend().get_texts()] == labels
    finally:
        plt.close(fig)
