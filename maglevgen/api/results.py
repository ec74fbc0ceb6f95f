"""The API's result types: frozen dataclasses of what each command prints or writes."""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas

__all__ = ["EnvelopeResult", "Gains", "MonteCarloResult", "RegionResult", "ReportResult",
           "SimulationResult", "SimulationRuns", "TrimResult"]


@dataclass(frozen=True)
class TrimResult:
    """The equilibrium at one speed: what ``maglevgen trim --json`` prints.

    Attributes
    ----------
    speed : float
        Forward speed [m/s].
    x : numpy.ndarray
        (12,) trim state in the order of `state_names` (units: m, rad, m/s, rad/s).
    state_names : tuple of str
        x, y, z, phi, theta, psi, u, v, w, p, q, r.
    propulsion_force : float
        F_prop [N] balancing the drag (and m a when accelerating).
    residual : float
        Largest absolute acceleration left by the Newton solve.
    lift_off_speed : float
        The lowest speed with an equilibrium [m/s].
    array_names : tuple of str
        The arrays in the parameter file's order.
    gaps, lift, drag : numpy.ndarray
        Per array: air gap [m], lift and drag [N] (eqs 4-5).
    stiffness_matrix : numpy.ndarray
        (5, 5) magnetic stiffness K_st0 on (y, z, phi, theta, psi) (eqs 13-19).
    report : dict
        The whole ``trim --json`` report (the stiffness table beside the paper's printed
        forms, the paper's inputs), without the envelope's verdicts.
    acceleration : float
        Along-track acceleration a [m/s^2] of the equilibrium (0: constant speed).
    """

    speed: float
    x: np.ndarray
    state_names: tuple[str, ...]
    propulsion_force: float
    residual: float
    lift_off_speed: float
    array_names: tuple[str, ...]
    gaps: np.ndarray
    lift: np.ndarray
    drag: np.ndarray
    stiffness_matrix: np.ndarray
    report: dict[str, Any] = field(repr=False)
    acceleration: float

    def to_dict(self) -> dict[str, Any]:
        """The report as plain JSON data (a copy).

        Returns
        -------
        dict
            What ``maglevgen trim --json`` prints, less its ``envelope`` entry.

        Examples
        --------
        >>> import maglevgen
        >>> sorted(maglevgen.load().trim().to_dict())[:3]
        ['acceleration', 'arrays', 'lift_off_speed']
        """
        return json.loads(json.dumps(self.report))


@dataclass(frozen=True)
class Gains:
    """A controller's gains at one speed, in the law of the generated C (eqs 20-33).

    u_gen = -(K_pos (a - a_trim) + K_rate a'), with a = (y, z, phi, theta, psi) and a' their
    rates; equivalently u_gen = -K (x_r - x_r,trim) on the reduced state x_r (`states`).
    The array forces are T u_gen (the minimum-norm allocation, eqs 22-23).

    Attributes
    ----------
    controller : str
        none, damping (eqs 20-21), lqr (per-axis LQR, eqs 24-33) or coupled (full-state LQR
        of the ten-state linearisation with the per-axis weights).
    speed : float
        Forward speed [m/s].
    K_pos, K_rate : numpy.ndarray
        (5, 5) position and rate gains [N/m, N*m/rad; N*s/m, N*m*s/rad].
    K : numpy.ndarray
        (5, 10) the same law on the reduced state; NaN where the coupled LQR's Riccati
        equation has no stabilizing solution.
    allocation : numpy.ndarray
        T (n_array_forces, 5) of the parameter file's ``control.actuators``: (10, 5) for the
        paper's y and z forces (eqs 22-23), (6, 5) for one force along each normal (then of
        rank 4 with the LLNL geometry: the pseudoinverse of E).
    poles : numpy.ndarray
        The ten closed-loop poles [1/s] of the reduced linearisation with this controller:
        the eigenvalues ``Carriage.envelope`` judges.
    states : tuple of str
        y, z, phi, theta, psi, v, w, p, q, r.
    controls : tuple of str
        u_y, u_z, u_phi, u_theta, u_psi.
    """

    controller: str
    speed: float
    K_pos: np.ndarray
    K_rate: np.ndarray
    K: np.ndarray
    allocation: np.ndarray
    poles: np.ndarray
    states: tuple[str, ...]
    controls: tuple[str, ...]


@dataclass(frozen=True)
class SimulationResult:
    """One closed-loop run of ``maglevgen simulate``, as named arrays.

    Attributes
    ----------
    controller : str
        The controller of the run.
    scenario : str
        hold or launch.
    t : numpy.ndarray
        (n,) time [s].
    x : numpy.ndarray
        (n, 12) state, columns `state_names`.
    u : numpy.ndarray
        (n, n_u) inputs [N], columns `input_names` (F_prop, then the array forces).
    gaps : numpy.ndarray
        (n, n_arrays) air gap of each array [m], columns `gap_names`.
    status : str
        settled, not settled, diverging, contact or generated code error.
    event : str or None
        What ended the run early (contact, a non-finite state), or None.
    metrics : dict
        The run's entry of metrics.json: settling time, peak and final deviation, RMS
        control per axis, the smallest gap, the speeds.
    state_names, input_names, gap_names : tuple of str
        Column names (those of the CSV files the CLI writes).
    units : dict
        Unit of every column name, t included.
    dt_limit : float
        RK4's stability limit [s] for the stiffest closed-loop mode at the start.
    specification : str or None
        The run against the controller's run specification (``[control.spec]``), in words;
        None without one.
    check : dict or None
        With ``check=True``: per state the largest deviation from SciPy's adaptive DOP853 on
        the lambdified SymPy model (``max_abs``, ``relative_to_peak``); else None.
    """

    controller: str
    scenario: str
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    gaps: np.ndarray
    status: str
    event: str | None
    metrics: dict[str, Any]
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    gap_names: tuple[str, ...]
    units: dict[str, str]
    dt_limit: float
    specification: str | None
    check: dict[str, dict[str, float]] | None

    def to_dataframe(self) -> pandas.DataFrame:
        """The run as a pandas DataFrame: one row per sample, the CSV file's columns.

        Returns
        -------
        pandas.DataFrame
            Columns t, the states, the inputs and the gaps (units in `units`), indexed by
            sample.

        Raises
        ------
        ImportError
            pandas is not installed (``pip install pandas``; it is optional).

        Examples
        --------
        >>> import maglevgen
        >>> run = maglevgen.load().simulate(controller="lqr", t_end=0.1)
        >>> df = run.to_dataframe()
        >>> list(df.columns[:4]), len(df)
        (['t', 'x', 'y', 'z'], 101)
        """
        try:
            import pandas as pd
        except ImportError as exc:
            raise ImportError("SimulationResult.to_dataframe needs pandas: "
                              "pip install pandas") from exc
        cols = ("t", *self.state_names, *self.input_names, *self.gap_names)
        return pd.DataFrame(np.column_stack([self.t, self.x, self.u, self.gaps]), columns=cols)


@dataclass(frozen=True)
class SimulationRuns:
    """The closed-loop runs of ``maglevgen simulate``, one per controller, from one trim.

    Attributes
    ----------
    runs : dict of str to SimulationResult
        Per controller, in the order asked for: its run.
    scenario : str
        hold or launch.
    speed : float
        The speed of the trim the runs start from [m/s] (the launch's: envelope.v_min).
    propulsion_force : float
        F_prop [N] at that trim.
    release_speed : float or None
        The launch's release speed (envelope.v_max) [m/s]; None for hold.
    dt_limit : float
        RK4's stability limit [s] for the stiffest closed-loop mode at the start.
    warning : str or None
        One line when the hold speed lies outside the envelope, else None.
    paths : tuple of pathlib.Path
        The files written (``out``: trajectories, metrics, figures), else empty.
    """

    runs: dict[str, SimulationResult]
    scenario: str
    speed: float
    propulsion_force: float
    release_speed: float | None
    dt_limit: float
    warning: str | None
    paths: tuple[Path, ...]


@dataclass(frozen=True)
class EnvelopeResult:
    """Each controller's closed-loop stability across [v_min, v_max]: ``maglevgen envelope``.

    Attributes
    ----------
    speeds : numpy.ndarray
        The speeds [m/s], evenly spaced over [v_min, v_max].
    v_min, v_max : float
        The envelope [m/s] (v_min from the lift-off speed when the file omits it).
    max_real : dict of str to numpy.ndarray
        Per controller: the largest real part [1/s] of the ten-state closed loop per speed.
    min_damping : dict of str to numpy.ndarray
        Per controller: the smallest damping ratio per speed.
    stable : dict of str to numpy.ndarray
        Per controller: every real part below -1e-6 1/s, per speed.
    unstable_ranges : dict of str to tuple
        Per controller: the (low, high) speed intervals where it is unstable, edges bisected.
    verdicts : dict of str to str
        Per controller: the verdict line the CLI prints.
    speed_pole : numpy.ndarray
        The forward-speed mode under the trim propulsion [1/s] per speed: the speed eigenvalue
        of the embedded controller's 12-state closed loop
        (``maglevgen.control.operating.SpeedMode``).
    paths : tuple of pathlib.Path
        The files written (``out``), else empty.
    report : dict
        What ``maglevgen envelope --json`` prints.
    lines : tuple of str
        The verdict lines ``maglevgen envelope`` prints, the embedded controller marked.
    """

    speeds: np.ndarray
    v_min: float
    v_max: float
    max_real: dict[str, np.ndarray]
    min_damping: dict[str, np.ndarray]
    stable: dict[str, np.ndarray]
    unstable_ranges: dict[str, tuple[tuple[float, float], ...]]
    verdicts: dict[str, str]
    speed_pole: np.ndarray
    paths: tuple[Path, ...]
    report: dict[str, Any] = field(repr=False)
    lines: tuple[str, ...] = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The envelope as plain JSON data (a copy).

        Returns
        -------
        dict
            What ``maglevgen envelope --json`` prints.

        Examples
        --------
        >>> import maglevgen
        >>> env = maglevgen.load().envelope(n_speeds=5)
        >>> len(env.to_dict()["speeds"])
        5
        """
        return json.loads(json.dumps(self.report))


@dataclass(frozen=True)
class RegionResult:
    """A sampled region of attraction per controller and speed: ``maglevgen roa``.

    Attributes
    ----------
    speeds : numpy.ndarray
        The speeds [m/s].
    levels : dict of str to numpy.ndarray
        Per controller: the level c of V = dx' P dx per speed (0: no region).
    extents : dict of str to dict
        Per controller and axis (y, z, phi, theta, psi): the largest deviation of that axis
        alone inside {V <= c} [m, rad] per speed.
    disturbance_multiple : dict of str to numpy.ndarray
        Per controller: how many times the default disturbance fits inside, per speed.
    statement : str
        How the level was established (a sampled estimate, not a proof).
    paths : tuple of pathlib.Path
        The files written (``out``), else empty.
    report : dict
        What ``maglevgen roa --json`` prints.
    lines : tuple of str
        What ``maglevgen roa`` prints.
    """

    speeds: np.ndarray
    levels: dict[str, np.ndarray]
    extents: dict[str, dict[str, np.ndarray]]
    disturbance_multiple: dict[str, np.ndarray]
    statement: str
    paths: tuple[Path, ...]
    report: dict[str, Any] = field(repr=False)
    lines: tuple[str, ...] = field(repr=False)


@dataclass(frozen=True)
class MonteCarloResult(Mapping[str, Any]):
    """A Monte-Carlo study's summary, ``maglevgen montecarlo --json``, and the files written.

    Read as the summary itself (a mapping: ``result["controllers"]``).

    Attributes
    ----------
    summary : dict
        Per controller the contact probability with its 95 % Wilson interval, status counts,
        per-axis quantiles, the worst samples and the inputs the failures correlate with;
        the timing.
    paths : tuple of pathlib.Path
        The files written (``out``), else empty.
    """

    summary: dict[str, Any] = field(repr=False)
    paths: tuple[Path, ...]

    def __getitem__(self, key: str) -> Any:
        return self.summary[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.summary)

    def __len__(self) -> int:
        return len(self.summary)


@dataclass(frozen=True)
class ReportResult(Sequence[Path]):
    """The files ``maglevgen report`` wrote (a sequence of paths) and how LaTeX went.

    Attributes
    ----------
    paths : tuple of pathlib.Path
        The files written.
    out_dir : pathlib.Path
        The output folder.
    latex_tool : str or None
        latexmk or pdflatex, None when no TeX is installed.
    pdf : bool
        report.pdf was built.
    latex_seconds : float
        LaTeX's time [s].
    failed_checks : tuple of str
        The verification rows whose error exceeds their bound (each also a warning).
    """

    paths: tuple[Path, ...]
    out_dir: Path
    latex_tool: str | None
    pdf: bool
    latex_seconds: float
    failed_checks: tuple[str, ...]

    def __getitem__(self, index):  # Sequence's: an int or a slice
        return self.paths[index]

    def __len__(self) -> int:
        return len(self.paths)
