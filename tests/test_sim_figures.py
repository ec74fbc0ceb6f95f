"""The simulation figures' data (issue 39): every controller's line is visible, the travel one
subplot per controller of its departure from the reference travel, the oscillating states as
their peak envelope on a log axis; checked on the figure's own Line2D data of runs made up
here, whose departures and peaks the test knows (no simulation, no library)."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from maglevgen.analyses import sim_output
from maglevgen.analyses.simulate import Trajectory
from maglevgen.controllers import controller as registered

matplotlib.use("Agg")

CONTROLLERS = ("none", "damping", "lqr", "coupled", "spec")
V = 20.0  # [m/s] the made-up runs' trim speed
DT = 1e-3
T_END = 3.0


def _runs(speed_reference: bool = False) -> tuple[list[Trajectory], dict[str, np.ndarray]]:
    """Five runs that travel V t (or a ramp's integral) plus a departure of at most a few
    millimetres each (the test's truth), each with a decaying oscillation of its own in the
    axes; op a stand-in with the trim speed and a zero axis trim (all the figures read)."""
    t = np.arange(0.0, T_END + DT / 2, DT)
    v_ref = V + 2.0 * t if speed_reference else np.full(t.size, V)
    x_ref = 1.0 + cumulative_trapezoid(v_ref, t, initial=0.0)
    runs, truth = [], {}
    op = SimpleNamespace(speed=V, a_trim=np.zeros(5))
    for k, name in enumerate(CONTROLLERS):
        departure = 1e-3 * (k - 2) * (1.0 - np.exp(-t))  # [m]: -2 .. +2 mm, 0 for lqr
        x = np.zeros((t.size, 12))
        x[:, 0] = x_ref + departure
        x[:, 6] = v_ref
        for i, s in enumerate((1, 2, 3, 4, 5)):  # y, z, phi, theta, psi
            x[:, s] = 1e-3 * np.exp(-(0.5 + k) * t) * np.cos((10 + i) * t)
        runs.append(Trajectory(name, op, DT, t, x, np.zeros((t.size, 11)),
                               np.full((t.size, 6), 0.015), 0,
                               speed_reference=v_ref if speed_reference else None,
                               scenario="launch" if speed_reference else "hold"))
        truth[name] = departure
    return runs, truth


def _figure(monkeypatch, draw, *args):
    """The matplotlib figure a figure function draws (its close() recorded, not done)."""
    import matplotlib.pyplot as plt

    seen = []
    monkeypatch.setattr(plt, "close", lambda fig=None: seen.append(fig))
    png = draw(*args)
    assert png.startswith(b"\x89PNG")
    (fig,) = seen
    return fig


def _peaks(t: np.ndarray, y: np.ndarray, window: float) -> np.ndarray:
    """The largest |y| in each whole window of ``window`` seconds, by a loop over windows."""
    n = round(window / (t[1] - t[0]))
    return np.array([max(abs(v) for v in y[i:i + n]) for i in range(0, t.size - n + 1, n)])


@pytest.mark.parametrize("launch", [False, True])
def test_travel_is_one_subplot_per_controller_of_its_departure(monkeypatch, launch) -> None:
    """travel_roll.png: the travel row holds one axes per controller, each with that
    controller's one line in its registry style, whose data is the made-up departure (x less
    the reference travel: the trim speed's, or the speed loop's ramp integrated) in mm; the
    roll row has every controller's line in both columns, the right one the peak envelope on
    a log axis."""
    runs, truth = _runs(speed_reference=launch)
    name, title, panels, figs = sim_output.FIGURES[1]
    assert name == "travel_roll.png" and panels[0][0] == "x"
    fig = _figure(monkeypatch, sim_output.figure_png, runs, title, panels, figs)
    travel = [a for a in fig.axes if a.get_title() in {sim_output._label(r) for r in runs}]
    assert [a.get_title() for a in travel] == [sim_output._label(r) for r in runs]
    for ax, run in zip(travel, runs, strict=True):
        (line,) = ax.get_lines()  # one controller per subplot: none hidden under another
        style = registered(run.controller).style
        assert matplotlib.colors.same_color(line.get_color(), style["color"])
        assert line.get_linestyle() == {"-": "-", "--": "--", ":": ":"}[style["ls"]]
        t, y = line.get_xydata().T
        np.testing.assert_allclose(y, np.interp(t, run.t, truth[run.controller]) * 1e3,
                                   rtol=1e-9, atol=1e-9)
    roll = [a for a in fig.axes if a not in travel]
    assert len(roll) == 2 and roll[1].get_yscale() == "log"
    for ax in roll:
        assert len(ax.get_lines()) == len(runs)
    for line, run in zip(roll[1].get_lines(), runs, strict=True):
        want = _peaks(run.t, run.x[:, 3] * 1e3, sim_output.PEAK_WINDOW)
        np.testing.assert_allclose(line.get_ydata(), want, rtol=1e-12)
    # the legend beside the roll envelope names every controller once
    legend = roll[1].get_legend()
    assert [t.get_text() for t in legend.get_texts()] == [sim_output._label(r) for r in runs]


def test_travel_departure_is_x_less_the_reference_travel() -> None:
    """travel_departure against scipy's cumulative trapezoid of the reference speed."""
    for launch in (False, True):
        runs, truth = _runs(speed_reference=launch)
        for run in runs:
            np.testing.assert_allclose(sim_output.travel_departure(run), truth[run.controller],
                                       rtol=0, atol=1e-9)


def test_launch_against_speed_draws_every_controller_and_the_peak_envelope(monkeypatch) -> None:
    """against_speed.png: per state a raw column (the first ZOOM_SECONDS) and a log column of
    the peak envelope against the speed at each window's centre, each with every controller's
    line; the peaks those of the made-up runs (a loop over windows here)."""
    runs, _ = _runs(speed_reference=True)
    fig = _figure(monkeypatch, sim_output.speed_figure_png, runs)
    assert len(fig.axes) == 6
    for row, state in enumerate((2, 4, 3)):  # z, theta, phi
        raw, env = fig.axes[2 * row], fig.axes[2 * row + 1]
        assert raw.get_yscale() == "linear" and env.get_yscale() == "log"
        assert len(raw.get_lines()) == len(env.get_lines()) == len(runs)
        for line, run in zip(env.get_lines(), runs, strict=True):
            want = _peaks(run.t, run.x[:, state] * 1e3, sim_output.PEAK_WINDOW)
            np.testing.assert_allclose(line.get_ydata(), want, rtol=1e-12)
            assert np.all(np.diff(line.get_xdata()) > 0)  # against the (rising) speed
            assert line.get_xdata()[0] >= V and line.get_xdata()[-1] <= V + 2.0 * T_END
        for line, run in zip(raw.get_lines(), runs, strict=True):
            near = run.t <= sim_output.ZOOM_SECONDS
            np.testing.assert_allclose(line.get_xydata(),
                                       np.column_stack([V + 2.0 * run.t[near],
                                                        run.x[near, state] * 1e3]), rtol=1e-12)
