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

The package: ``results`` (the result types), ``arguments`` (the argument checks, each naming
its option), ``core`` (`CarriageCore`: the parameters, model and library, trim, gains and
linear models), ``studies`` (runs, envelope, Monte Carlo, region of attraction) and
``writers`` (C, firmware, report, FMU, build); `Carriage` is the three classes together.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from maglevgen.api.core import AXES as AXES  # the axes' and states' names (maglevgen.api.AXES)
from maglevgen.api.core import STATE_NAMES as STATE_NAMES
from maglevgen.api.core import CarriageCore
from maglevgen.api.results import (
    EnvelopeResult,
    Gains,
    MonteCarloResult,
    RegionResult,
    ReportResult,
    SimulationResult,
    SimulationRuns,
    TrimResult,
)
from maglevgen.api.studies import Studies
from maglevgen.api.writers import Writers

__all__ = ["AXES", "STATE_NAMES", "Carriage", "EnvelopeResult", "Gains", "MonteCarloResult",
           "RegionResult", "ReportResult", "SimulationResult", "SimulationRuns", "TrimResult",
           "load"]


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


class Carriage(Studies, Writers, CarriageCore):
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
