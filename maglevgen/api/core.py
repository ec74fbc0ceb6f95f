"""The carriage's core: parameters, model and library; trim, gains and linear models."""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from maglevgen.api.arguments import MAX_ACCELERATION, check_controller, commands
from maglevgen.api.results import Gains, TrimResult
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError

if TYPE_CHECKING:
    import control

    from maglevgen.carriage import DerivedCarriage
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.control.operating import OperatingPoint
    from maglevgen.params import Parameters
    from maglevgen.runtime.library import SimulationLibrary

__all__ = ["AXES", "STATE_NAMES", "CarriageCore"]

STATE_NAMES: tuple[str, ...] = tuple(s.name for s in cv.STATES)
AXES: tuple[str, ...] = tuple(cv.AXES)


class CarriageCore:
    """What a carriage's methods share: its validated parameters, model and compiled
    library, the checks of a speed; and the methods on one operating point (trim, gains,
    linear models). `maglevgen.Carriage` is this with the studies and the writers."""

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
    def _plant(self) -> Plant:
        """The one `Plant` of this carriage (library, speed range, operating points, loop as
        built) that every study and writer hands down; its library loads on first use, the
        steps announced on stderr (`queries.plant_of`)."""
        return commands().plant_of(self._carriage)

    @property
    def _lib(self) -> SimulationLibrary:
        return self._plant.lib

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
        rep = commands().trim_report(self._plant, v, acceleration=float(acceleration))
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
        return commands().gains_report(self._plant, v)

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
        entry, lines = commands().envelope_verdicts(self._plant)
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
        controller : str, optional
            A registered controller (``maglevgen.controllers.names()``: the paper's ``none``,
            ``damping``, ``lqr`` and ``coupled``, ``spec``, and any registered since; default
            the paper's per-axis LQR).

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

        check_controller(controller)
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
        queries = commands()
        v = self._speed(speed)
        lib = self._lib
        v = queries.trim_point(self._plant, v).speed  # or no trim
        k, m = (float(a.ravel()[i]) for a in lib.function("maglev_axis_plants")(
            v, self._carriage.p))
        q = cv.Q_STATES[i]
        return control.ss([[0.0, 1.0], [-k / m, 0.0]], [[0.0], [1.0 / m]], [[1.0, 0.0]], 0.0,
                          states=[q, f"{q}_dot"], inputs=[cv.CONTROLS[i].name], outputs=[q],
                          name=name)
