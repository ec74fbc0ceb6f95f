"""The Python API: a carriage as an object, its results as numpy arrays and python-control
systems.

Every method mirrors a command of ``maglevgen`` (the CLI) and calls the same functions, so the
numbers are the ones the command prints, and bad input raises the same exception
(`maglevgen.InputError`, exit code 2 on the command line) with the same one-line message
(which names the command-line option, e.g. ``--speed``, that the argument stands for).

========================  ===================================================
``maglevgen.load``        ``--params FILE --set NAME=VALUE``
``Carriage.trim``         ``maglevgen trim --json``
``Carriage.gains_report`` ``maglevgen gains --json``
``Carriage.gains``        the 5 x 5 gains the simulation, envelope and FMU use
``Carriage.linearize``    the Jacobians of the compiled ``maglev_jacobians``
``Carriage.axis_plant``   one axis of ``maglevgen gains`` (eqs 24-27)
``Carriage.verdicts``     the envelope's verdicts ``trim`` and ``gains`` print
``Carriage.simulate``     one run of ``maglevgen simulate``
``Carriage.simulations``  ``maglevgen simulate``
``Carriage.envelope``     ``maglevgen envelope``
``Carriage.roa``          ``maglevgen roa``
``Carriage.montecarlo``   ``maglevgen montecarlo``
``Carriage.generate``     ``maglevgen generate``
``Carriage.firmware``     ``maglevgen firmware``
``Carriage.report``       ``maglevgen report``
``Carriage.fmu``          ``maglevgen fmu``
``Carriage.build``        ``maglevgen build``
========================  ===================================================

Every option of a command is a parameter of its method (tests/test_cli_api.py checks it), and
the command is a printer over the method: it parses its arguments, calls the method and prints
what the method returns. ``progress=True`` announces the slow steps on stderr as the command
does.

The state, input and output names of the python-control systems are those of the generated C
(``manifest.json``): states x, y, z, phi, theta, psi (position of O and Z-Y-X Euler angles) and
u, v, w, p, q, r (body velocities and rates); inputs F_prop and the array force components.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from maglevgen.control import embeddable as embeddable_controllers
from maglevgen.control import names as controller_names
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError, VerificationError
from maglevgen.exports.fmu import DEFAULT_FMI
from maglevgen.infrastructure import progress as steps  # the commands' progress lines (stdlib only)

if TYPE_CHECKING:
    import control
    import pandas

    from maglevgen.analyses.simulate import SimulationRun, Trajectory
    from maglevgen.build import BuildResult
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.control.operating import OperatingPoint
    from maglevgen.params import Parameters
    from maglevgen.runtime.library import SimulationLibrary

__all__ = ["Carriage", "EnvelopeResult", "Gains", "MonteCarloResult", "RegionResult",
           "ReportResult", "SimulationResult", "SimulationRuns", "TrimResult", "load"]

STATE_NAMES: tuple[str, ...] = tuple(s.name for s in cv.STATES)
AXES: tuple[str, ...] = tuple(cv.AXES)


def load(params: str | Path | None = None, overrides: Sequence[str] = ()) -> Carriage:
    """Load and validate a carriage's parameter file, as every command does.

    Parameters
    ----------
    params : str or pathlib.Path, optional
        The TOML parameter file (``--params``); None: the LLNL carriage shipped with
        maglevgen (``maglevgen params show``).
    overrides : sequence of str, optional
        ``NAME=VALUE`` items (``--set``): dotted names as in the file, values in TOML syntax,
        e.g. ``("vehicle.mass=12.5", "arrays.3.circuits=12")``.

    Returns
    -------
    Carriage
        The validated carriage.

    Raises
    ------
    maglevgen.InputError
        A file that cannot be read, malformed TOML, an unknown key, a value outside its
        physical range; the message is the CLI's one line, naming the key and the value.

    See Also
    --------
    Carriage : the same, as a constructor.

    Examples
    --------
    >>> import maglevgen
    >>> carriage = maglevgen.load(overrides=["vehicle.mass=12.5"])
    >>> carriage.params.vehicle.mass
    12.5
    >>> maglevgen.load(overrides=["vehicle.mass=-1"])
    Traceback (most recent call last):
    ...
    maglevgen.errors.InputError: carriage_llnl.toml: vehicle.mass = -1: ...
    """
    return Carriage(params, overrides)


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


class Carriage:
    """A carriage: its validated parameters, model, compiled library and results.

    The numbers come from the same functions as the ``maglevgen`` commands: trim and gains
    reports from ``maglevgen trim`` / ``gains``; the linearisation, the gains the simulation
    uses, the simulation and the envelope from the compiled run-time-parameter library
    (``maglev_trim``, ``maglev_lqr_gains``, ``maglev_jacobians``, ``maglev_simulate``). The
    library is generated and compiled once per carriage structure and cached
    (``~/.cache/maglevgen`` or ``$MAGLEVGEN_CACHE``).

    Parameters
    ----------
    params : str or pathlib.Path, optional
        The TOML parameter file; None: the LLNL carriage shipped with maglevgen.
    overrides : sequence of str, optional
        ``NAME=VALUE`` items as ``--set`` takes them.

    Raises
    ------
    maglevgen.InputError
        An invalid parameter file or override (the CLI's one-line message).

    See Also
    --------
    load : the same, as a function.

    Examples
    --------
    >>> import maglevgen
    >>> carriage = maglevgen.Carriage()
    >>> carriage.state_names[:6]
    ('x', 'y', 'z', 'phi', 'theta', 'psi')
    >>> carriage.input_names[:3]
    ('F_prop', 'F_y1', 'F_z1')
    """

    def __init__(self, params: str | Path | None = None, overrides: Sequence[str] = ()) -> None:
        from maglevgen.params import load_params

        self._loaded = load_params(params, overrides)  # checks both arguments' types too
        self._source, self._overrides = params, self._loaded.overrides  # what `build` rereads

    def __repr__(self) -> str:
        loaded = self._loaded
        extra = f", overrides={list(loaded.overrides)!r}" if loaded.overrides else ""
        return f"maglevgen.Carriage({loaded.source!r}{extra})"

    # ------------------------------------------------------------------------ properties

    @property
    def params(self) -> Parameters:
        """The validated parameters (a pydantic model; ``maglevgen params schema``)."""
        return self._loaded.params

    @property
    def sha256(self) -> str:
        """SHA-256 of the parameter text and overrides (``params_sha256`` of every output)."""
        return self._loaded.sha256

    @property
    def state_names(self) -> tuple[str, ...]:
        """The 12 states: x, y, z [m], phi, theta, psi [rad], u, v, w [m/s], p, q, r [rad/s]."""
        return STATE_NAMES

    @property
    def state_units(self) -> dict[str, str]:
        """Unit of each state."""
        return {s.name: s.unit for s in cv.STATES}

    @property
    def input_names(self) -> tuple[str, ...]:
        """F_prop and the force component of each array [N]: F_y1, F_z1, ... (eqs 22-23,
        control.actuators = "paper") or F_n1, ... along the normals ("normal")."""
        from maglevgen.derive.structure import input_names_of

        return tuple(input_names_of(self._carriage.structure))

    @property
    def array_names(self) -> tuple[str, ...]:
        """The arrays, in the parameter file's order."""
        return tuple(self.params.arrays)

    @cached_property
    def _carriage(self) -> DerivedCarriage:
        """The model, built when a method first needs it: after its options are checked
        (bad input is refused before any work, as on the command line)."""
        from maglevgen.carriage import DerivedCarriage

        return DerivedCarriage(self._loaded)

    @cached_property
    def _lib(self) -> SimulationLibrary:
        return _commands().library_of(self._carriage)

    # ----------------------------------------------------------------------- checks

    def _speed(self, speed: float | None) -> float:
        """The speed asked for, checked as ``--speed`` is; None: operation.speed."""
        from maglevgen.params import check_key_option

        if speed is None:
            return float(self.params.operation.speed)
        check_key_option("--speed", speed, "operation.speed")
        return float(speed)

    def _operating_point(self, speed: float | None) -> OperatingPoint:
        from maglevgen.control.operating import Weights, operating_point

        v = self._speed(speed)  # before the library is built
        return operating_point(self._lib, self._carriage.p, v,
                               self.params.track.min_gap, Weights.of(self.params))

    # --------------------------------------------------------------------- trim, gains

    def trim(self, speed: float | None = None, acceleration: float = 0.0) -> TrimResult:
        """The equilibrium at a speed: state, array gaps and forces, stiffness (eqs 4-19).

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; default ``operation.speed`` of the parameter file.
        acceleration : float, optional
            Along-track acceleration a [m/s^2] (default 0, constant speed): the accelerating
            trim, eqs 1-2 with the d'Alembert load -m a at the CG and the propulsion
            (drag + m a) at operation.propulsion_point (``maglev_trim_accelerating``).

        Returns
        -------
        TrimResult
            The numbers ``maglevgen trim --json`` prints.

        Raises
        ------
        maglevgen.InputError
            A speed outside operation.speed's range (message names ``--speed``), a non-finite
            acceleration (``--acceleration``).
        maglevgen.NoTrimError
            No equilibrium at this speed (below lift-off) or a gap below track.min_gap.

        Examples
        --------
        >>> import maglevgen
        >>> trim = maglevgen.load().trim(20.0)
        >>> trim.speed, trim.x.shape, trim.array_names
        (20.0, (12,), ('1', '2', '3', '4', '5', '6'))
        >>> bool(trim.lift_off_speed < 20.0 and trim.gaps.min() > 0)
        True
        >>> launch = maglevgen.load().trim(20.0, acceleration=5.0)  # nose down, more thrust
        >>> bool(launch.x[4] < trim.x[4] and launch.propulsion_force > trim.propulsion_force)
        True
        """
        from maglevgen.params import check_option

        v = self._speed(speed)
        check_option("--acceleration", acceleration, -MAX_ACCELERATION, MAX_ACCELERATION,
                     "m/s^2", "braking or launching at up to 100 g")
        rep = _commands().trim_report(self._carriage, v, acceleration=float(acceleration))
        arrays = rep["arrays"]
        names = tuple(arrays)
        return TrimResult(
            speed=rep["speed"], x=np.array([rep["state"][s] for s in STATE_NAMES]),
            state_names=STATE_NAMES, propulsion_force=rep["propulsion_force"],
            residual=rep["residual"], lift_off_speed=rep["lift_off_speed"], array_names=names,
            gaps=np.array([arrays[n]["gap"] for n in names]),
            lift=np.array([arrays[n]["lift"] for n in names]),
            drag=np.array([arrays[n]["drag"] for n in names]),
            stiffness_matrix=np.array(rep["stiffness_matrix"]), report=rep,
            acceleration=rep["acceleration"])

    def gains_report(self, speed: float | None = None) -> dict[str, Any]:
        """The per-axis LQR report of ``maglevgen gains --json`` (eqs 24-33).

        Per axis the plant m a'' + k a = u, the closed-form LQR gain, the numerical one
        (CARE), the paper's eq 32 gain and their accuracy against a 50-digit reference; the
        per-axis design on the coupled linearisation beside the coupled LQR; the allocation
        (eqs 22-23).

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; default ``operation.speed``.

        Returns
        -------
        dict
            What ``maglevgen gains --json`` prints, less its ``envelope`` entry.

        Raises
        ------
        maglevgen.InputError
            A speed outside operation.speed's range.
        maglevgen.NoTrimError
            No equilibrium at this speed.

        Examples
        --------
        >>> import maglevgen
        >>> rep = maglevgen.load().gains_report(20.0)
        >>> list(rep["axes"])
        ['lateral', 'vertical', 'roll', 'pitch', 'yaw']
        >>> len(rep["axes"]["vertical"]["K_closed_form"])
        2
        """
        v = self._speed(speed)  # before the model is built
        return _commands().gains_report(self._carriage, v)

    def verdicts(self) -> tuple[dict[str, Any], tuple[str, ...]]:
        """The envelope's verdicts that ``maglevgen trim`` and ``gains`` print first.

        Each controller's verdict on the continuous linearisation and the run
        specification across [v_min, v_max] (as `envelope`, without the embedded
        controller's check on the other models).

        Returns
        -------
        entry : dict
            What ``trim --json`` and ``gains --json`` hold under ``"envelope"``: v_min,
            v_max, the embedded controller, the verdicts and whether each is stable; or
            ``{"error": ...}``, why the envelope could not be computed (no trim at one of
            its ends).
        lines : tuple of str
            The lines the commands print.

        Raises
        ------
        maglevgen.MaglevError
            A failure other than bad input (an envelope with no trim is reported in
            ``entry``, not raised).

        Examples
        --------
        >>> import maglevgen
        >>> entry, lines = maglevgen.load().verdicts()
        >>> entry["embedded"], lines[0].startswith("Envelope")
        ('spec', True)
        """
        entry, lines = _commands().envelope_verdicts(self._carriage)
        return entry, tuple(lines)

    def gains(self, speed: float | None = None, controller: str = "lqr") -> Gains:
        """A controller's gains at a speed, as the compiled simulation and the FMU use them.

        Per-axis LQR and damping gains from ``maglev_lqr_gains`` (closed forms of eqs 21
        and 33 in the generated C); the coupled LQR from SciPy's CARE on the compiled
        Jacobians with the per-axis weights.

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; default ``operation.speed``.
        controller : {'lqr', 'coupled', 'damping', 'none'}, optional
            The controller (default the paper's per-axis LQR).

        Returns
        -------
        Gains
            K_pos, K_rate (5 x 5), K on the reduced state (5 x 10), the allocation and the
            closed-loop poles.

        Raises
        ------
        maglevgen.InputError
            An unknown controller, a speed outside operation.speed's range.
        maglevgen.NoTrimError
            No equilibrium at this speed.

        Examples
        --------
        >>> import numpy as np, maglevgen
        >>> g = maglevgen.load().gains(20.0, controller="coupled")
        >>> g.K_pos.shape, g.K.shape
        ((5, 5), (5, 10))
        >>> bool(np.all(g.poles.real < 0))
        True
        >>> lqr = maglevgen.load().gains(20.0, controller="lqr")  # the circuits' lag beats it
        >>> bool(np.all(lqr.poles.real < 0))
        False
        """
        from maglevgen.control.operating import N_AXES, REDUCED_STATES

        _check_controller(controller)
        op = self._operating_point(speed)
        K_pos, K_rate = op.gains(controller)
        K = K_pos @ np.eye(N_AXES, len(REDUCED_STATES)) + K_rate @ op.rate_map
        A_cl = op.reduced_closed_loop(controller)
        poles = (np.linalg.eigvals(A_cl) if np.all(np.isfinite(A_cl))
                 else np.full(len(REDUCED_STATES), np.nan + 0j))
        return Gains(controller, op.speed, K_pos, K_rate, K, op.allocation.copy(), poles,
                     REDUCED_STATES, tuple(c.name for c in cv.CONTROLS))

    # ----------------------------------------------------------------- linear models

    def linearize(self, speed: float | None = None, model: str = "full") -> control.StateSpace:
        """The linearisation at the trim of a speed, as a python-control state space.

        From the compiled ``maglev_jacobians`` (eqs 10-12 linearised; the stiffness of
        eqs 13-19 is its magnetic part). Deviations from trim: dx' = A dx + B du, y = dx.

        ``model='full'``: 12 states x, y, z [m], phi, theta, psi [rad], u, v, w [m/s],
        p, q, r [rad/s]; inputs F_prop and the array forces [N] (`input_names`); the outputs
        are the states. ``model='reduced'``: the ten states y, z, phi, theta, psi, v, w, p,
        q, r (x drops out; u is held by the propulsion) driven by the generalized forces
        u_y, u_z [N], u_phi, u_theta, u_psi [N*m] through the allocation T (eqs 22-23): the
        plant the coupled LQR and ``envelope`` use.

        Parameters
        ----------
        speed : float, optional
            Forward speed [m/s]; default ``operation.speed``.
        model : {'full', 'reduced'}, optional
            Which model (default 'full').

        Returns
        -------
        control.StateSpace
            Named states, inputs and outputs; named ``maglev`` or ``maglev_reduced``.

        Raises
        ------
        maglevgen.InputError
            An unknown model, a speed outside operation.speed's range.
        maglevgen.NoTrimError
            No equilibrium at this speed.

        Examples
        --------
        >>> import maglevgen
        >>> sys = maglevgen.load().linearize(20.0)
        >>> sys.nstates, sys.ninputs, sys.noutputs
        (12, 11, 12)
        >>> sys.input_labels[:2], sys.state_labels[2]
        (['F_prop', 'F_y1'], 'z')
        >>> maglevgen.load().linearize(20.0, model="reduced").ninputs
        5
        """
        import control

        from maglevgen.control.operating import REDUCED_STATES

        if model not in ("full", "reduced"):
            raise InputError(f"model {model!r}: expected 'full' or 'reduced'")
        op = self._operating_point(speed)
        if model == "full":
            A, B, states, inputs = op.A, op.B, list(STATE_NAMES), list(self.input_names)
        else:
            (A, B), states = op.reduced, list(REDUCED_STATES)
            inputs = [c.name for c in cv.CONTROLS]
        n = A.shape[0]
        return control.ss(A, B, np.eye(n), np.zeros((n, B.shape[1])), states=states,
                          inputs=inputs, outputs=states,
                          name="maglev" if model == "full" else "maglev_reduced")

    def axis_plant(self, axis: str, speed: float | None = None) -> control.StateSpace:
        """One axis' plant m a'' + k a = u of the per-axis design (eqs 24-27).

        k: the axis' total stiffness at trim (magnetic K_st0 plus the gravity and propulsion
        moments), m: its generalized mass, the numbers ``maglevgen gains`` prints
        (``stiffness``, ``inertia``). State (a, a'), input the generalized force u, output a.

        Parameters
        ----------
        axis : str
            lateral, vertical, roll, pitch or yaw; or the coordinate y, z, phi, theta, psi.
        speed : float, optional
            Forward speed [m/s]; default ``operation.speed``.

        Returns
        -------
        control.StateSpace
            A = [[0, 1], [-k/m, 0]], B = [[0], [1/m]], C = [1, 0], D = 0; units m or rad,
            N or N*m.

        Raises
        ------
        maglevgen.InputError
            An unknown axis, a speed outside operation.speed's range.
        maglevgen.NoTrimError
            No equilibrium at this speed.

        Examples
        --------
        >>> import control, maglevgen
        >>> heave = maglevgen.load().axis_plant("vertical", 20.0)
        >>> heave.state_labels, heave.input_labels, heave.output_labels
        (['z', 'z_dot'], ['u_z'], ['z'])
        >>> K, _, _ = control.lqr(heave, [[1, 0], [0, 1]], 1)
        >>> K.shape
        (1, 2)
        """
        import control

        coords = dict(zip(cv.Q_STATES, AXES, strict=True))
        name = coords.get(axis, axis) if isinstance(axis, str) else None
        if name not in AXES:
            raise InputError(f"axis {axis!r}: expected one of {', '.join(AXES)} "
                             f"(or {', '.join(cv.Q_STATES)})")
        i = AXES.index(name)
        queries = _commands()
        v = self._speed(speed)
        lib = queries.library_of(self._carriage)
        v = queries.trim_point(self._carriage, lib, v).speed  # or no trim
        k, m = (float(a.ravel()[i]) for a in lib.function("maglev_axis_plants")(
            v, self._carriage.p))
        q = cv.Q_STATES[i]
        return control.ss([[0.0, 1.0], [-k / m, 0.0]], [[0.0], [1.0 / m]], [[1.0, 0.0]], 0.0,
                          states=[q, f"{q}_dot"], inputs=[cv.CONTROLS[i].name], outputs=[q],
                          name=name)

    # ---------------------------------------------------------------- time domain

    def simulate(self, controller: str = "lqr", scenario: str = "hold",
                 speed: float | None = None, t_end: float = 10.0,
                 dt: float = 1e-3, loop: str = "firmware",
                 disturbance: Mapping[str, float] | Sequence[str] | None = None
                 ) -> SimulationResult:
        """A closed-loop run in the compiled C, as ``maglevgen simulate`` (figs 3-8).

        From the trim disturbed by 1 mm lateral and heave, 2 mrad roll, pitch and yaw; RK4
        in ``maglev_simulate`` (``hold``: the propulsion at the trim drag, the gains of
        ``speed``) or ``maglev_launch`` (``launch``: from the accelerating trim at
        envelope.v_min to v_max, the gains scheduled with the measured speed, the reference
        and the propulsion those of the accelerating trim at envelope.launch_acceleration).

        Parameters
        ----------
        controller : {'lqr', 'coupled', 'damping', 'none'}, optional
            The controller (default the paper's per-axis LQR).
        scenario : {'hold', 'launch'}, optional
            The run (default hold).
        speed : float, optional
            Forward speed of ``hold`` [m/s]; default ``operation.speed``. Not for ``launch``.
        t_end : float, optional
            Simulated time of ``hold`` [s] (default 10); ``launch`` runs until v_max.
        dt : float, optional
            RK4 step [s] (default 1e-3); refused above RK4's stability limit.
        loop : {'firmware', 'continuous'}, optional
            ``firmware`` (default): the firmware tick's law at the tick of
            ``[control.spec]`` with its delay, each controller's gains on the loop as built
            (the ``spec`` design at the tick), the speed loop and the force budget, on the
            plant with the actuator lag of ``[actuators]`` (``--loop``); ``continuous``: the
            paper's law at every RK4 stage under the trim propulsion.
        disturbance : mapping of str to float, or sequence of str, optional
            The initial deviation from trim (``--disturbance``): state name to value
            (m, rad, m/s, rad/s; at most 0.1 in magnitude), or ``"STATE=VALUE"`` items; given,
            only these states are disturbed. None: the default disturbance above.

        Returns
        -------
        SimulationResult
            t, x, u, gaps, status, metrics and the column names.

        See Also
        --------
        simulations : several controllers, the files and the reference check.

        Raises
        ------
        maglevgen.InputError
            An unknown controller or scenario, t_end or dt outside their ranges, a step
            above the stability limit, a speed with ``launch``.
        maglevgen.NoTrimError
            No equilibrium at the speed.

        Examples
        --------
        >>> import maglevgen
        >>> run = maglevgen.load().simulate(controller="damping", t_end=10.0)
        >>> run.status, run.x.shape, float(run.t[-1])
        ('settled', (10001, 12), 10.0)
        >>> run.metrics["axes"]["vertical"]["unit"]
        'm'
        """
        _check_controller(controller)
        return self.simulations(controller, scenario, speed, t_end, dt, loop,
                                disturbance).runs[controller]

    def simulations(self, controller: str = "all", scenario: str = "hold",
                    speed: float | None = None, t_end: float = 10.0, dt: float = 1e-3,
                    loop: str = "firmware",
                    disturbance: Mapping[str, float] | Sequence[str] | None = None,
                    check: bool = False, out: str | Path | None = None,
                    progress: bool = False) -> SimulationRuns:
        """The closed-loop runs of ``maglevgen simulate``: one per controller, the files, the
        reference check (figs 3-8).

        The runs of `simulate`, from the same trim, in the compiled C.

        Parameters
        ----------
        controller : str, optional
            A registered controller or ``"all"`` (default; ``--controller``).
        scenario : {'hold', 'launch'}, optional
            The run (default hold; ``--scenario``).
        speed : float, optional
            Forward speed of ``hold`` [m/s] (``--speed``); default ``operation.speed``.
        t_end : float, optional
            Simulated time of ``hold`` [s] (default 10; ``--t-end``).
        dt : float, optional
            RK4 step [s] (default 1e-3; ``--dt``).
        loop : {'firmware', 'continuous'}, optional
            How each controller runs (``--loop``; see `simulate`).
        disturbance : mapping of str to float, or sequence of str, optional
            The initial deviation from trim (``--disturbance``; see `simulate`).
        check : bool, optional
            Also integrate each run with SciPy's adaptive DOP853 (rtol 1e-12) on the
            lambdified SymPy model (``--check``; seconds per run; ``loop='continuous'``
            only): `SimulationResult.check`.
        out : str or pathlib.Path, optional
            Write trajectories.npz, the CSV files, metrics.json, metrics.md and the figures
            there (``--out``).
        progress : bool, optional
            Announce the slow steps (and a speed outside the envelope) on stderr.

        Returns
        -------
        SimulationRuns
            Per controller its `SimulationResult`; the start trim, the files.

        Raises
        ------
        maglevgen.InputError
            An unknown controller or scenario, t_end or dt outside their ranges, a step
            above the stability limit, a speed with ``launch``, a disturbance of an unknown
            state or above 0.1, ``check`` without ``loop='continuous'``.
        maglevgen.NoTrimError
            No equilibrium at the speed.

        Examples
        --------
        >>> import maglevgen
        >>> runs = maglevgen.load().simulations(t_end=0.5, disturbance={"z": 0.002})
        >>> list(runs.runs), runs.scenario
        (['none', 'damping', 'lqr', 'coupled', 'spec'], 'hold')
        >>> float(runs.runs["spec"].x[0, 2] - runs.runs["spec"].x[-1, 2]) > 0
        True
        """
        from maglevgen.analyses.simulate import run_scenarios

        if controller != "all":
            _check_controller(controller)
        out = None if out is None else _path("--out", out)
        if _flag("--check", check) and loop != "continuous":
            raise InputError("--check: the DOP853 reference integrates the continuous "
                             "control law; add --loop continuous")
        if speed is not None:
            self._speed(speed)
        _check_run_options(t_end, dt)
        initial = _disturbance(disturbance)  # before the library: bad input is one line
        if out is not None:
            from maglevgen.infrastructure.output import check_writable

            check_writable(Path(out))  # before any work: a folder of the user's is refused
        controllers = controller_names() if controller == "all" else (controller,)
        # the library if this carriage has built it (cached_property's entry), else the one
        # run_scenarios builds after checking its options: bad input stays the only line
        lib = self.__dict__.get("_lib")
        run = run_scenarios(self._carriage, controllers, t_end, dt, speed, lib=lib,
                            announce=steps.step if progress else None,
                            bar=steps.bar if progress else None, scenario=scenario,
                            disturbance=initial, loop=loop)
        paths: tuple[Path, ...] = ()
        if out is not None:
            from maglevgen.analyses.sim_output import render_results
            from maglevgen.codegen.generate import write_output

            files = render_results(run.trajectories, run.input_names,
                                   run.header(self._carriage.loaded.sha256))
            paths = tuple(write_output(files, Path(out)))
        if run.warning and progress:
            steps.step(f"warning: {run.warning}")
        checks: dict[str, dict] = {}
        if check:
            from maglevgen.analyses.simulate import reference_check

            if progress:
                steps.step("checking against DOP853 (rtol 1e-12) on the lambdified model")
            for traj in run.trajectories:
                checks[traj.controller] = reference_check(self._carriage.functions,
                                                          self._carriage.p, traj)
        return SimulationRuns(
            runs={t.controller: _simulation_result(run, t, checks.get(t.controller))
                  for t in run.trajectories},
            scenario=run.scenario, speed=run.op.speed, propulsion_force=run.op.f_prop,
            release_speed=run.v_end, dt_limit=run.dt_limit, warning=run.warning, paths=paths)

    def envelope(self, n_speeds: int | None = None, out: str | Path | None = None,
                 progress: bool = False) -> EnvelopeResult:
        """Each controller's closed-loop stability across [v_min, v_max], with verdicts.

        The eigenvalues of the ten-state linearisation (`linearize` with
        ``model='reduced'``) with each controller closed around it (`gains`), at evenly
        spaced speeds; the edges of an unstable range located by bisection.

        Parameters
        ----------
        n_speeds : int, optional
            Speeds spanning the envelope (``--speeds``; default 50).
        out : str or pathlib.Path, optional
            Also write envelope.json, envelope.md and stability_map.png there (``--out``).
        progress : bool, optional
            Announce the computation on stderr once the arguments are checked.

        Returns
        -------
        EnvelopeResult
            Per controller the largest real part, smallest damping, verdict and unstable
            ranges.

        Raises
        ------
        maglevgen.InputError
            n_speeds outside 2 to 100000, an envelope with no trim at one of its ends.

        Examples
        --------
        >>> import maglevgen
        >>> env = maglevgen.load().envelope(n_speeds=10)
        >>> env.speeds.size, sorted(env.verdicts)
        (10, ['coupled', 'damping', 'lqr', 'none', 'spec'])
        >>> env.verdicts["coupled"][:6]
        'stable'
        """
        from maglevgen.analyses.envelope import DEFAULT_SPEEDS, MAX_SPEEDS
        from maglevgen.params import check_count

        queries = _commands()
        out = None if out is None else _path("--out", out)
        if n_speeds is not None:  # 0 is refused, not the default
            check_count("--speeds", n_speeds, 2, MAX_SPEEDS, "speeds spanning the envelope")
        if out is not None:
            from maglevgen.infrastructure.output import check_writable

            check_writable(Path(out))  # before any work: a folder of the user's is refused
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce("envelope: each controller's closed-loop eigenvalues at "
                           f"{n_speeds or DEFAULT_SPEEDS} speeds")
        env = queries.envelope_of(self._carriage, n_speeds)
        rep = env.to_json()
        paths: tuple[Path, ...] = ()
        if out is not None:
            from maglevgen.analyses.envelope import envelope_markdown, stability_map_png
            from maglevgen.infrastructure.output import write_output

            paths = tuple(write_output({"envelope.json": json.dumps(rep, indent=1) + "\n",
                                        "envelope.md": envelope_markdown(env),
                                        "stability_map.png": stability_map_png(env)},
                                       Path(out)))
        c = env.controllers
        return EnvelopeResult(
            speeds=env.speeds, v_min=env.v_min, v_max=env.v_max,
            max_real={n: e.max_real for n, e in c.items()},
            min_damping={n: e.min_damping for n, e in c.items()},
            stable={n: e.stable for n, e in c.items()},
            unstable_ranges={n: e.unstable_ranges for n, e in c.items()},
            verdicts={n: e.verdict for n, e in c.items()}, speed_pole=env.speed_pole,
            paths=paths, report=rep,
            lines=tuple(queries.verdict_lines(env, self.params.envelope.embedded_controller)))

    def montecarlo(self, samples: int = 1000, seed: int = 0, controller: str | None = None,
                   t_end: float = 10.0, dt: float = 1e-3, workers: int | None = None,
                   scheduler: str | None = None, out: str | Path | None = None,
                   loop: str = "firmware", progress: bool = False,
                   redesign: bool = False) -> MonteCarloResult:
        """Monte-Carlo robustness over the parameter file's ``[tolerances]``, as
        ``maglevgen montecarlo``.

        Each sample draws the toleranced parameters, a speed and an initial disturbance from
        its own ``numpy.random.SeedSequence(seed, spawn_key=(i,))``, so the results do not
        depend on the worker count; the compiled C trims the sample (eqs 1-4, 8-12) and runs
        the closed loop (RK4) of every controller asked for, designed (eqs 20-33) on the
        nominal carriage at the sample's speed, as the firmware flies (``redesign``: on the
        sample's own parameters instead).

        Parameters
        ----------
        samples : int, optional
            Number of sampled carriages (default 1000).
        seed : int, optional
            Seed of the study (default 0).
        controller : str, optional
            A registered controller (``"spec"``, ``"coupled"``, ...) or ``"all"``; default the
            embedded controller (``envelope.embedded_controller``).
        t_end : float, optional
            Length of each run in s (default 10).
        dt : float, optional
            RK4 step in s (default 1e-3).
        workers : int, optional
            Local processes (default every core) or Dask workers of a ``"local"`` cluster.
        scheduler : str, optional
            ``None`` (local processes), ``"local"`` (a Dask LocalCluster) or the address of
            an existing Dask scheduler (``"tcp://host:8786"``).
        out : str or pathlib.Path, optional
            Folder for ``samples.parquet``, ``montecarlo.md``/``.json`` and the plots.
        loop : {'firmware', 'continuous'}, optional
            How every run executes its controller (``--loop``; see `simulate`).
        progress : bool, optional
            Announce the study once the arguments are checked, the slow steps on stderr,
            and the runs' rate (a progress bar on a terminal).
        redesign : bool, optional
            Re-design each sample's controller for its own parameters, as if the firmware
            knew them (``--redesign``; default False: the nominal design, as flown).

        Returns
        -------
        MonteCarloResult
            The summary ``maglevgen montecarlo --json`` prints (read as a mapping): per
            controller the contact probability with its 95 % Wilson interval, status counts,
            per-axis quantiles, the worst samples and the inputs the failures correlate with;
            and the files written.

        Raises
        ------
        maglevgen.InputError
            A bad option (the CLI's one-line message), or an unreachable scheduler.

        Examples
        --------
        >>> import maglevgen
        >>> s = maglevgen.load().montecarlo(samples=4, seed=1, t_end=0.5, workers=1)
        >>> sorted(s["controllers"])
        ['spec']
        """
        from maglevgen.analyses.montecarlo import (
            MAX_SAMPLES,
            check_scheduler,
            default_workers,
            make_study,
            output_files,
            run_study,
        )
        from maglevgen.analyses.simulate import run_loop
        from maglevgen.infrastructure.output import check_writable, write_output
        from maglevgen.params import check_count

        choice = _controller_choice(controller, self.params.envelope.embedded_controller)
        check_count("--samples", samples, 1, MAX_SAMPLES, "the samples' table is held in "
                    "memory")
        check_count("--seed", seed, 0, _MAX_SEED, "numpy's SeedSequence takes non-negative "
                    "integers")
        if workers is not None:
            check_count("--workers", workers, 1, MAX_WORKERS, "a process per worker")
        _check_run_options(t_end, dt)
        _check_loop(loop)
        check_scheduler(scheduler)
        if out is not None:
            out = _path("--out", out)
            check_writable(out)
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce(f"montecarlo: {samples} samples over [tolerances], the compiled "
                           "library and the study first")
        controllers = controller_names() if choice == "all" else (choice,)
        lib = self._lib
        study = make_study(self._carriage, lib, controllers, t_end, dt, seed,
                           *run_loop(self._carriage, lib, loop),
                           redesign=_flag("--redesign", redesign))
        k = len(controllers)
        if progress:
            with steps.rate_bar("Monte Carlo", samples * k) as tick:
                result = run_study(study, samples, workers or default_workers(), scheduler,
                                   tick=lambda n: tick(n * k))
        else:
            result = run_study(study, samples, workers or default_workers(), scheduler)
        paths: tuple[Path, ...] = ()
        if out is not None:
            paths = tuple(write_output(output_files(result), Path(out)))
        return MonteCarloResult(result.summary, paths)

    def roa(self, n_speeds: int | None = None, controller: str | None = None,
            samples: int | None = None, seed: int = 0, workers: int = 1,
            batch: int | None = None, out: str | Path | None = None,
            progress: bool = False) -> RegionResult:
        """A sampled region of attraction per speed, as ``maglevgen roa``.

        V = dx' P dx on the ten reduced states (P from the design's Lyapunov / Riccati
        equation); the largest level c with dV/dt < 0 on the nonlinear closed loop (the
        generated C, batched in ``maglev_lyapunov_batch``) and every gap above track.min_gap
        at every sampled state of {V <= c}, then confirmed by runs of the firmware loop from
        states on {V = c} (`maglevgen.analyses.roa`). A sampled estimate, not a proof.

        Parameters
        ----------
        n_speeds : int, optional
            Speeds spanning [v_min, v_max] (``--speeds``; default 8).
        controller : str, optional
            A registered controller or ``"all"`` (``--controller``); default the embedded one.
        samples : int, optional
            Random directions per speed (``--samples``; default 3000).
        seed : int, optional
            Seed of the directions (``--seed``).
        workers : int, optional
            Threads evaluating the batches (``--workers``); the numbers do not change.
        batch : int, optional
            States per C call (``--batch``); the numbers do not change.
        out : str or pathlib.Path, optional
            Also write roa.json, roa.md and roa_extent.png there (``--out``).
        progress : bool, optional
            Announce the sampling on stderr once the arguments are checked.

        Returns
        -------
        RegionResult
            Per controller and speed the level, the extents and the default's multiple.

        Raises
        ------
        maglevgen.InputError
            A bad option (the CLI's one-line message).

        Examples
        --------
        >>> import maglevgen
        >>> r = maglevgen.load().roa(n_speeds=2, samples=50)
        >>> sorted(r.levels)
        ['spec']
        """
        from maglevgen.analyses import roa
        from maglevgen.infrastructure.output import check_writable, write_output
        from maglevgen.params import check_count

        choice = _controller_choice(controller, self.params.envelope.embedded_controller)
        if n_speeds is not None:
            check_count("--speeds", n_speeds, 1, roa.MAX_SPEEDS, "speeds spanning the "
                        "envelope")
        if samples is not None:
            check_count("--samples", samples, 1, roa.MAX_DIRECTIONS, "directions per speed, "
                        "held in memory")
        if batch is not None:
            check_count("--batch", batch, 1, roa.MAX_BATCH, "states per C call, held in "
                        "memory")
        check_count("--seed", seed, 0, _MAX_SEED, "numpy's SeedSequence takes non-negative "
                    "integers")
        check_count("--workers", workers, 1, MAX_WORKERS, "a thread per worker")
        out = None if out is None else _path("--out", out)
        base = roa.COMMAND_SAMPLING
        sampling = roa.Sampling(directions=base.directions if samples is None else samples,
                                radii=base.radii, bisections=base.bisections,
                                confirm=base.confirm, seed=seed,
                                batch=base.batch if batch is None else batch, workers=workers)
        if out is not None:
            check_writable(Path(out))
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce(f"roa: sampling the region of attraction of {choice} at "
                           f"{n_speeds or roa.DEFAULT_SPEEDS} speeds, "
                           f"{sampling.directions} directions each")
        controllers = controller_names() if choice == "all" else (choice,)
        regions = roa.study(self._carriage, self._lib, controllers,
                            roa.DEFAULT_SPEEDS if n_speeds is None else n_speeds, sampling)
        paths: tuple[Path, ...] = ()
        if out is not None:
            paths = tuple(write_output(roa.study_files(regions), Path(out)))
        return RegionResult(
            speeds=regions[0].speeds,
            levels={r.controller: np.array([s.level for s in r.regions]) for r in regions},
            extents={r.controller: {a: np.array([s.extents[a] for s in r.regions])
                                    for a in roa.AXIS_NAMES} for r in regions},
            disturbance_multiple={r.controller: np.array([s.disturbance_multiple
                                                          for s in r.regions])
                                  for r in regions},
            statement=regions[0].statement(), paths=paths, report=roa.study_json(regions),
            lines=tuple(roa.study_lines(regions, self.params.envelope.embedded_controller)))

    # -------------------------------------------------------------------- writers

    def generate(self, out: str | Path, precision: str = "double", parameters: str = "baked",
                 int_type: str = "int64", single_file: bool = False) -> list[Path]:
        """Generate the carriage's C, as ``maglevgen generate``.

        The dynamics (eqs 10-12), Jacobians, Newton trim, gain schedule, per-tick
        controllers (eqs 20-33), allocation (eqs 22-23), RK4 step, ``maglev_simulate``;
        ``maglev.h``, ``manifest.json``, a CMake file and an example ``main.c``.

        Parameters
        ----------
        out : str or pathlib.Path
            Output folder (written atomically; created if missing).
        precision : {'double', 'single'}, optional
            Floating-point type of the C (default double).
        parameters : {'baked', 'runtime'}, optional
            Fold the parameter values in, or take them as an input vector p; baked also
            bakes the envelope's speed range, the trim's accepted speeds.
        int_type : {'int64', 'int32'}, optional
            casadi_int (``--int``): int64 (long long, as casadi.external expects) or int32
            (int, for 32-bit MCUs).
        single_file : bool, optional
            One translation unit, maglev.c, with only the headers' API external
            (``--single-file``).

        Returns
        -------
        list of pathlib.Path
            The files written.

        Raises
        ------
        maglevgen.InputError
            An unknown precision, parameters mode or int type.

        Examples
        --------
        >>> import tempfile, maglevgen
        >>> with tempfile.TemporaryDirectory() as out:
        ...     names = [p.name for p in maglevgen.load().generate(out)]
        >>> "maglev.h" in names and "manifest.json" in names
        True
        """
        from maglevgen.analyses.verdicts import generate_example
        from maglevgen.codegen.generate import GenerateOptions, render, write_output

        out = _path("--out", out)
        for option, value in (("--precision", precision), ("--parameters", parameters),
                              ("--int", int_type)):
            _choice_text(option, value)
        opts = GenerateOptions(precision, parameters, int_type,
                               _flag("--single-file", single_file))  # checks them
        speeds = None
        if opts.parameters == "baked":  # the trim's accepted speeds baked with the parameters
            from maglevgen.analyses.envelope import speed_range

            speeds = speed_range(self._carriage)
        # main.c's example: the embedded controller at a speed where it is verified
        example = generate_example(self._carriage, self._lib)
        return list(write_output(render(self._carriage, opts, speeds, example), Path(out)))

    def firmware(self, out: str | Path, precision: str = "single",
                 with_plant: bool = False, allow_unstable: bool = False) -> list[Path]:
        """Write the embedded controller's firmware folder, as ``maglevgen firmware``.

        The C of ``envelope.embedded_controller``'s path only, parameters baked: the table
        schedule ``maglev_schedule``, the controller's per-tick function and the allocation
        (eqs 22-23), ``maglev_tick`` (the speed loop and the force budget around them), an
        example ``main.c``, a CMake project with a Cortex-M4F toolchain file, the MISRA
        deviation list and a README saying what to call when.

        Parameters
        ----------
        out : str or pathlib.Path
            Output folder (written atomically; created if missing).
        precision : {'single', 'double'}, optional
            single for the board (default); double to check the same code on a host.
        with_plant : bool, optional
            Also ``maglev_dynamics`` (the plant) in the image: a closed loop on the target.
        allow_unstable : bool, optional
            Write the folder even when the embedded controller fails the check ``build``
            exits 3 on (its verdict then says so in the README and manifest).

        Returns
        -------
        list of pathlib.Path
            The files written.

        Raises
        ------
        maglevgen.InputError
            An unknown precision, or a folder that cannot be written.
        maglevgen.VerificationError
            The embedded controller fails ``build``'s check (unstable somewhere in the
            envelope, a spec of ``[control.spec]`` or a judged run): nothing is written.

        Examples
        --------
        >>> import tempfile, maglevgen
        >>> with tempfile.TemporaryDirectory() as out:
        ...     names = [p.name for p in maglevgen.load().firmware(out)]
        >>> "maglev_tick.c" in names
        True
        """
        from maglevgen.codegen.generate import GenerateOptions
        from maglevgen.exports.firmware import firmware_files
        from maglevgen.infrastructure.output import check_writable, write_output

        out = _path("--out", out)
        _flag("--with-plant", with_plant)
        _flag("--allow-unstable", allow_unstable)
        check_writable(out)
        GenerateOptions(precision, "baked")  # an unknown precision: InputError first
        verdict = self._verified(allow_unstable)
        return list(write_output(firmware_files(self._carriage, precision, with_plant,
                                                verdict.to_json()), Path(out)))

    def _verified(self, allow_unstable: bool, progress: bool = False):
        """The embedded controller's verdict (`maglevgen.build.verify_embedded`, cached);
        a VerificationError (exit 3) when it fails and ``allow_unstable`` is not set."""
        from maglevgen.build import verify_embedded

        verdict = verify_embedded(self._carriage, self._lib,
                                  steps.step if progress else _quiet)
        if not verdict.verified and not allow_unstable:
            raise VerificationError(f"{verdict.reason}: nothing written")
        return verdict

    def report(self, out: str | Path, simulation: str | Path | None = None,
               progress: bool = False) -> ReportResult:
        """Write the derivation report, as ``maglevgen report``.

        ``report.tex`` and, where TeX is installed, ``report.pdf``: every equation of the
        paper re-derived beside its printed form, with numeric checks. A missing TeX, or a
        verification whose error exceeds its bound, gives a `UserWarning` (the CLI's
        message).

        Parameters
        ----------
        out : str or pathlib.Path
            Output folder.
        simulation : str or pathlib.Path, optional
            A folder written by ``maglevgen simulate --out``: include its figures.
        progress : bool, optional
            Announce the slow steps on stderr, and say there what would be warnings (the
            command's lines).

        Returns
        -------
        ReportResult
            The files written (a sequence of paths) and how LaTeX went.

        Raises
        ------
        maglevgen.InputError
            A simulation folder that does not hold a simulation's output.

        Examples
        --------
        >>> import tempfile, maglevgen
        >>> import warnings
        >>> with tempfile.TemporaryDirectory() as out, warnings.catch_warnings():
        ...     warnings.simplefilter("ignore")  # the per-axis LQR's failed envelope check
        ...     names = [p.name for p in maglevgen.load().report(out)]
        >>> "report.tex" in names
        True
        """
        from maglevgen.report import INSTALL_HINT, ReportOptions, write_report

        out = _path("--out", out)
        opts = ReportOptions(simulation=None if simulation is None
                             else _path("--simulation", simulation))
        res = write_report(self._carriage, Path(out), opts,
                           progress=steps.step if progress else _quiet)
        # a note and warnings: lines on stderr with `progress` (the command's), else warnings
        notes = ([f"no LaTeX found: wrote report.tex without report.pdf; to build the PDF "
                  f"install TeX ({INSTALL_HINT}) and rerun"] if res.latex.tool is None else [])
        failed = [f"verification failed: {what} (see the report's Verification)"
                  for what in res.failed_checks]
        if progress:
            for line in (*notes, *(f"warning: {m}" for m in failed)):
                steps.step(line)
        else:
            for message in (*notes, *failed):
                warnings.warn(message, stacklevel=2)
        return ReportResult(tuple(res.paths), res.out_dir, res.latex.tool, res.latex.ok,
                            res.latex.seconds, tuple(res.failed_checks))

    def fmu(self, out: str | Path, kind: str = "both", controller: str | None = None,
            fmi: str = DEFAULT_FMI, loop: str = "firmware", progress: bool = False,
            allow_unstable: bool = False) -> Path:
        """Export an FMI 2.0 or 3.0 FMU of the carriage with its controller, as ``maglevgen
        fmu``.

        Parameters
        ----------
        out : str or pathlib.Path
            Output folder of ``maglev.fmu``.
        kind : {'both', 'me', 'cs'}, optional
            Model exchange, co-simulation or both (default).
        controller : {'coupled', 'lqr', 'damping', 'none', 'external'}, optional
            The controller inside the FMU (default: ``envelope.embedded_controller``, the
            one the firmware embeds); ``external``: the generalized forces are inputs.
        fmi : {'2', '3'}, optional
            The FMI version (``--fmi``): 2.0 (default,
            ``maglevgen.exports.fmu.DEFAULT_FMI``) or 3.0, the same variables.
        loop : {'firmware', 'continuous'}, optional
            ``--loop``: the loop as built, as ``simulate(loop="firmware")`` flies it
            (default): the built-in controller's tick law at the tick of ``[control.spec]``
            with its delay and its gains at the tick, the speed loop and its integral, the
            force budget and each array force's first-order lag in the plant (model
            exchange: as continuous states); or the paper's law at every derivative
            evaluation (the start values of the FMU's tick parameters).
        progress : bool, optional
            Announce the slow steps (code generation, compilation) on stderr.
        allow_unstable : bool, optional
            Write the FMU of the embedded controller even when it fails the check ``build``
            exits 3 on (its description then says so).

        Returns
        -------
        pathlib.Path
            The FMU written.

        Raises
        ------
        maglevgen.InputError
            An unknown kind, controller or FMI version, FMPy (its FMI headers) missing, no
            trim at operation.speed.

        Examples
        --------
        >>> import tempfile, maglevgen
        >>> with tempfile.TemporaryDirectory() as out:
        ...     path = maglevgen.load().fmu(out, kind="cs")
        ...     size = path.stat().st_size
        >>> path.name, size > 0
        ('maglev.fmu', True)
        """
        from maglevgen.exports.fmu import FMU_NAME, build_fmu
        from maglevgen.infrastructure.output import write_output

        out = _path("--out", out)
        _flag("--allow-unstable", allow_unstable)
        from maglevgen.exports.fmu import FMI_VERSIONS, FMU_LOOPS, KINDS

        # every choice before the verification (minutes) that the embedded controller gets
        for option, value, choices in (("--kind", kind, KINDS), ("--fmi", fmi, FMI_VERSIONS),
                                       ("--loop", loop, FMU_LOOPS)):
            _choice_text(option, value)
            if value not in choices:
                raise InputError(f"{option} {value!r}: expected one of {', '.join(choices)}")
        embedded = self.params.envelope.embedded_controller
        controller = embedded if controller is None else controller
        if controller != "external":
            _check_controller(controller)
        verdict: str | Callable[[], str]
        if controller == embedded:  # verified before anything is written (after the options)
            def verdict_now() -> str:
                return self._verified(allow_unstable, progress).text()
            verdict = verdict_now
        else:
            verdict = (f"controller {controller!r}: not the embedded controller {embedded!r}, "
                       "not verified by maglevgen against [control.spec]")
        data = build_fmu(self._carriage, kind, controller, fmi=fmi, loop=loop,
                         progress=steps.step if progress else _quiet, verdict=verdict)
        (path,) = write_output({FMU_NAME: data}, Path(out))
        return path

    def build(self, out: str | Path = "build", t_end: float = 10.0, dt: float = 1e-3,
              pdf: bool = True, controller: str | None = None, allow_unstable: bool = False,
              progress: bool = False) -> BuildResult:
        """The main job, as ``maglevgen build``: C, library, simulations, envelope, region of
        attraction and report brought up to date in one atomic step, with SUMMARY.md.

        The carriage's parameter file and overrides are read again: an up-to-date folder is
        recognised from their text and BUILD.json alone, and left as it is.

        Parameters
        ----------
        out : str or pathlib.Path, optional
            Output folder (default ``build``).
        t_end : float, optional
            Simulated time of the runs [s] (default 10; ``--t-end``).
        dt : float, optional
            RK4 step [s] (default 1e-3; ``--dt``).
        pdf : bool, optional
            Also build report.pdf where TeX is installed (``--no-pdf``: False).
        controller : str, optional
            The embeddable controller the firmware C embeds and the build verifies
            (``--controller``; the same as the override
            ``envelope.embedded_controller="NAME"``); default the file's.
        allow_unstable : bool, optional
            A failed verification (the embedded controller unstable somewhere in the
            envelope) is a warning, not a `maglevgen.VerificationError`.
        progress : bool, optional
            Announce the steps on stderr (a progress bar on a terminal).

        Returns
        -------
        maglevgen.build.BuildResult
            The folder, whether it was rebuilt, SUMMARY.md's text and the files.

        Raises
        ------
        maglevgen.InputError
            Bad parameters or options, an envelope without a trim, a folder that cannot be
            written.
        maglevgen.VerificationError
            The embedded controller fails the build's verification (exit 3 on the command
            line), unless ``allow_unstable``.

        Examples
        --------
        >>> import maglevgen
        >>> maglevgen.load().build("/nonexistent/x/build", dt=5.0)
        Traceback (most recent call last):
        ...
        maglevgen.errors.InputError: --dt 5: ...
        """
        from maglevgen.build import BuildOptions, build_folder

        out = _path("--out", out)
        _check_run_options(t_end, dt)  # their types too, before the options' JSON
        if controller is not None and (not isinstance(controller, str) or not controller):
            # (a name is checked by the schema, as envelope.embedded_controller)
            raise InputError(f"--controller {_shown(controller)}: expected one of "
                             f"{', '.join(embeddable_controllers())} (a controller the firmware "
                             "can embed)")
        opts = BuildOptions(t_end=t_end, dt=dt, pdf=_flag("--no-pdf", pdf),
                            allow_unstable=_flag("--allow-unstable", allow_unstable))
        res = build_folder(self._source, self._overrides, Path(out), opts, controller,
                           step=steps.step if progress else None,
                           bar=steps.bar if progress else None)
        for message in res.warnings(allow_unstable):
            warnings.warn(message, stacklevel=2)
        if (error := res.failure(allow_unstable)) is not None:
            raise error
        return res


def _commands() -> ModuleType:
    """The module holding the functions behind the commands (trim_report, gains_report,
    envelope_of, envelope_verdicts, verdict_lines, library_of): the one place this API
    names it."""
    from maglevgen.analyses import queries

    return queries


def _quiet(_message: str) -> None:
    """No progress (the methods' default: a script's stderr stays its own)."""


def _check_run_options(t_end: float, dt: float) -> None:
    from maglevgen.params import check_run_options

    check_run_options(t_end, dt)


#: the most worker processes or threads a study starts (more is a typo, not a machine)
MAX_WORKERS = 1024
#: the largest |acceleration| of an accelerating trim (envelope.launch_acceleration's bound)
MAX_ACCELERATION = 1e3
_MAX_PATH = 4096  # PATH_MAX
_MAX_SEED = 2**128 - 1  # numpy's SeedSequence's entropy: any non-negative int; bounded here


def _check_controller(controller: str) -> None:
    if not isinstance(controller, str) or controller not in (known := controller_names()):
        raise InputError(f"--controller {_shown(controller)}: expected one of "
                         f"{', '.join(known)}")


def _controller_choice(controller: str | None, embedded: str) -> str:
    """``--controller`` of a study: a registered name or "all"; None: the embedded one."""
    choice = embedded if controller is None else controller
    if choice != "all":
        _check_controller(choice)
    return choice


def _check_loop(loop: str) -> None:
    from maglevgen.analyses.simulate import LOOPS

    if not isinstance(loop, str) or loop not in LOOPS:
        raise InputError(f"--loop {_shown(loop)}: expected one of {', '.join(LOOPS)}")


def _path(option: str, value: object) -> Path:
    """A folder or file argument (``--out``, ``--simulation``) as a Path: a non-empty str or
    path-like without NUL, at most PATH_MAX long, or an InputError naming the option (a
    number or None gave a TypeError from pathlib, a NUL a ValueError)."""
    from maglevgen.infrastructure.text import check_text

    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text:
        raise InputError(f"{option} {_shown(value)}: expected a folder's path (a non-empty "
                         "str or pathlib.Path)")
    # a NUL no file name can hold (the OS's ValueError); other characters are the user's to
    # choose: a folder's name is shown escaped (shown_name), not refused
    bad = check_text(text, _MAX_PATH) if "\0" in text or len(text) > _MAX_PATH else None
    if bad is not None:
        raise InputError(f"{option} {_shown(value)}: the path {bad}")
    return Path(text)


def _choice_text(option: str, value: object) -> None:
    """A choice argument is a string (its own check then names the choices): a list or a
    dict gave "unhashable type" from the table it is looked up in."""
    if not isinstance(value, str):
        raise InputError(f"{option} {_shown(value)}: expected a string naming one of its "
                         "choices")


def _flag(option: str, value: object) -> bool:
    """A yes/no argument: True or False (a number or a string is a mistake: 'no' is true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{option} {_shown(value)}: expected True or False")
    return bool(value)


def _shown(value: object) -> str:
    """A bad argument's value in a one-line message: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _simulation_result(run: SimulationRun, traj: Trajectory,
                       check: dict | None) -> SimulationResult:
    """One run of a `SimulationRun`, with the CSV file's column names."""
    from maglevgen.analyses.sim_output import columns
    from maglevgen.analyses.simulate import metrics, spec_verdict

    verdict = spec_verdict(traj)
    cols = columns(run.input_names, traj.gaps.shape[1])
    names = [n for n, _ in cols]
    n_x, n_u = traj.x.shape[1], traj.u.shape[1]
    return SimulationResult(
        controller=traj.controller, scenario=traj.scenario, t=traj.t, x=traj.x, u=traj.u,
        gaps=traj.gaps, status=traj.status, event=traj.event, metrics=metrics(traj),
        state_names=tuple(names[1:1 + n_x]), input_names=tuple(names[1 + n_x:1 + n_x + n_u]),
        gap_names=tuple(names[1 + n_x + n_u:]), units=dict(cols), dt_limit=run.dt_limit,
        specification=None if verdict is None else verdict.text(), check=check)


def _disturbance(given: Mapping[str, float] | Sequence[str] | None) -> dict[str, float] | None:
    """The initial deviation from trim of ``--disturbance STATE=VALUE`` items, or of a
    mapping state -> value, checked (None: the default disturbance)."""
    if not given:
        return None
    if isinstance(given, str):  # one "STATE=VALUE" would iterate by character
        given = (given,)
    if not isinstance(given, Mapping) and not (
            isinstance(given, Sequence) and all(isinstance(i, str) for i in given)):
        raise InputError(f"--disturbance {_shown(given)}: expected STATE=VALUE strings or a "
                         "mapping state -> value")
    items = ([(f"{k}={v}", k, v) for k, v in given.items()] if isinstance(given, Mapping)
             else [(item, *item.partition("=")[::2]) for item in given])
    out = {}
    for item, name, raw in items:
        try:
            value = float(raw)
        except (TypeError, ValueError):
            value = math.nan
        if str(name).strip() not in cv.STATE_INDEX or not (math.isfinite(value)
                                                            and abs(value) <= 0.1):
            raise InputError(f"--disturbance {item!r}: expected STATE=VALUE with a state of "
                             f"{', '.join(cv.STATE_INDEX)} and |VALUE| <= 0.1")
        out[str(name).strip()] = value
    return out
