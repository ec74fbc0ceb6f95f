"""The carriage's writers: the C, the firmware folder, the report, the FMU, the build."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from maglevgen.api.arguments import (
    as_path,
    check_choice_text,
    check_controller,
    check_run_arguments,
    flag,
    loop_of,
    quiet,
    shown,
)
from maglevgen.api.core import CarriageCore
from maglevgen.api.results import ReportResult
from maglevgen.controllers import embeddable as embeddable_controllers
from maglevgen.errors import InputError, VerificationError
from maglevgen.exports.fmu import DEFAULT_FMI
from maglevgen.infrastructure import progress as steps  # the commands' progress lines (stdlib only)

if TYPE_CHECKING:
    from maglevgen.build import BuildResult

__all__ = ["Writers"]


class Writers(CarriageCore):
    """`maglevgen.Carriage`'s writers (``generate``, ``firmware``, ``report``, ``fmu``,
    ``build``)."""

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

        out = as_path("--out", out)
        for option, value in (("--precision", precision), ("--parameters", parameters),
                              ("--int", int_type)):
            check_choice_text(option, value)
        opts = GenerateOptions(precision, parameters, int_type,
                               flag("--single-file", single_file))  # checks them
        speeds = None
        if opts.parameters == "baked":  # the trim's accepted speeds baked with the parameters
            speeds = self._plant.speed_range
        # main.c's example: the embedded controller at a speed where it is verified
        example = generate_example(self._plant)
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

        out = as_path("--out", out)
        flag("--with-plant", with_plant)
        flag("--allow-unstable", allow_unstable)
        check_writable(out)
        GenerateOptions(precision, "baked")  # an unknown precision: InputError first
        verdict = self._verified(allow_unstable)
        return list(write_output(firmware_files(self._plant, precision, with_plant,
                                                verdict.to_json()), Path(out)))

    def _verified(self, allow_unstable: bool, progress: bool = False):
        """The embedded controller's verdict (`maglevgen.build.verify_embedded`, cached);
        a VerificationError (exit 3) when it fails and ``allow_unstable`` is not set."""
        from maglevgen.build import verify_embedded

        verdict = verify_embedded(self._plant, steps.step if progress else quiet)
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

        out = as_path("--out", out)
        opts = ReportOptions(simulation=None if simulation is None
                             else as_path("--simulation", simulation))
        res = write_report(self._carriage, Path(out), opts,
                           progress=steps.step if progress else quiet)
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
            fmi: str = DEFAULT_FMI, loop: str | None = None, progress: bool = False,
            allow_unstable: bool = False) -> Path:
        """Export an FMI 2.0 or 3.0 FMU of the carriage with its controller, as ``maglevgen
        fmu``.

        Parameters
        ----------
        out : str or pathlib.Path
            Output folder of ``maglev.fmu``.
        kind : {'both', 'me', 'cs'}, optional
            Model exchange, co-simulation or both (default).
        controller : str, optional
            A registered controller (``maglevgen.controllers.names()``) inside the FMU
            (default: ``envelope.embedded_controller``, the one the firmware embeds), or
            ``external``: the generalized forces are inputs.
        fmi : {'2', '3'}, optional
            The FMI version (``--fmi``): 2.0 (default,
            ``maglevgen.exports.fmu.DEFAULT_FMI``) or 3.0, the same variables.
        loop : {'sensed', 'firmware', 'continuous'}, optional
            ``--loop``: ``"sensed"``, the loop as a carriage flies it: the embedded
            controller's firmware sense tick (its Kalman filter and law, the firmware's C
            inside the FMU) on the plant's readings of ``[sensors]`` with noise the FMU
            draws from ``noise_seed``; ``"firmware"``, the loop as built on the exact state,
            as ``simulate(loop="firmware")`` flies it: the built-in controller's tick law at
            the tick of ``[control.spec]`` with its delay and its gains at the tick, the speed
            loop and its integral, the force budget and each array force's first-order lag in
            the plant (model exchange: as continuous states); ``"continuous"``, the paper's
            law at every derivative evaluation. Default: ``"sensed"`` for the embedded
            controller where the file has ``[sensors]``, else ``"firmware"``.
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

        out = as_path("--out", out)
        flag("--allow-unstable", allow_unstable)
        from maglevgen.exports.fmu import EXTERNAL, FMI_VERSIONS, FMU_LOOPS, KINDS

        # every choice before the verification (minutes) that the embedded controller gets
        for option, value, choices in (("--kind", kind, KINDS), ("--fmi", fmi, FMI_VERSIONS),
                                       *((("--loop", loop, FMU_LOOPS),) if loop is not None
                                         else ())):
            check_choice_text(option, value)
            if value not in choices:
                raise InputError(f"{option} {value!r}: expected one of {', '.join(choices)}")
        embedded = self.params.envelope.embedded_controller
        controller = embedded if controller is None else controller
        if controller != EXTERNAL.name:  # the FMU's own: the forces are inputs
            check_controller(controller)
        verdict: str | Callable[[], str]
        if controller == embedded:  # verified before anything is written (after the options)
            def verdict_now() -> str:
                return self._verified(allow_unstable, progress).text()
            verdict = verdict_now
        else:
            verdict = (f"controller {controller!r}: not the embedded controller {embedded!r}, "
                       "not verified by maglevgen against [control.spec]")
        # this carriage's plant; its library, when not loaded yet, loads announced only with
        # progress (as `simulate`'s)
        plant = self._plant
        if not plant.loaded:
            from maglevgen.control.carriage_plant import Plant

            plant = self.__dict__["_plant"] = Plant(
                self._carriage, progress=steps.step if progress else quiet)
        data = build_fmu(plant, kind, controller, fmi=fmi,
                         loop=None if loop is None else loop_of(loop, FMU_LOOPS),
                         progress=steps.step if progress else quiet, verdict=verdict)
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

        out = as_path("--out", out)
        check_run_arguments(t_end, dt)  # their types too, before the options' JSON
        if controller is not None and (not isinstance(controller, str) or not controller):
            # (a name is checked by the schema, as envelope.embedded_controller)
            raise InputError(f"--controller {shown(controller)}: expected one of "
                             f"{', '.join(embeddable_controllers())} (a controller the firmware "
                             "can embed)")
        opts = BuildOptions(t_end=t_end, dt=dt, pdf=flag("--no-pdf", pdf),
                            allow_unstable=flag("--allow-unstable", allow_unstable))
        res = build_folder(self._source, self._overrides, Path(out), opts, controller,
                           step=steps.step if progress else None,
                           bar=steps.bar if progress else None)
        for message in res.warnings(allow_unstable):
            warnings.warn(message, stacklevel=2)
        if (error := res.failure(allow_unstable)) is not None:
            raise error
        return res
