"""The `maglevgen` command: a printer over the Python API (maglevgen/api/).

Each command parses its arguments, calls the API method of the same name (`build`, which
answers an up-to-date folder without numpy, calls the function that method calls:
`maglevgen.build.build_folder`) and prints what it returns; the checks of the input and the
files written are the API's. Every option is a parameter of that method
(tests/test_cli_api.py). Errors are one line on stderr; exit 0 success, 2 bad input, 1
internal failure, 3 failed verification. ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import errno
import gc
import json
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from maglevgen.derive import conventions as cv
from maglevgen.errors import MaglevError
from maglevgen.infrastructure.columns import fcolumn_plain
from maglevgen.infrastructure.text import shown_name
from maglevgen.version import __version__

if TYPE_CHECKING:
    from maglevgen.api import Carriage

__all__ = ["build_parser", "main"]

# The API (numpy) and the parameter schema (pydantic) are imported by the commands that need
# them, so that `maglevgen --help` and `maglevgen build` on an up-to-date folder answer
# without loading them.


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE", help="parameter file (default: the LLNL carriage)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], dest="overrides",
                   help="override a parameter, dotted name as in the file, a key with dots quoted: "
                        'tolerances.parameters."vehicle.mass".normal=0.2 (repeatable)')
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--t-end", type=float, default=10.0, metavar="S",
                   help="simulated time [s] (default 10)")
    p.add_argument("--dt", type=float, default=1e-3, metavar="S",
                   help="RK4 step [s] (default 1e-3)")


def _loop_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--loop", choices=("firmware", "sensed", "continuous"), default=None,
                   help="default: as a carriage flies, sensed for the embedded controller "
                        "alone where the file has [sensors], else firmware. sensed: the "
                        "embedded controller as the firmware flies it on the sensors of "
                        "[sensors], its sense tick (Kalman filter and law, compiled from the "
                        "firmware's C) on noisy readings (seeded); firmware: the firmware "
                        "tick's law at the tick of [control.spec] with its delay, each "
                        "controller's gains on the loop as built, the speed loop and the "
                        "force budget, on the plant with the actuator lag of [actuators], the "
                        "state measured exactly (ideal sensing); continuous: the paper's law "
                        "at every RK4 stage under the trim propulsion")


def _carriage(args: argparse.Namespace) -> Carriage:
    """The API's carriage of ``--params`` and ``--set`` (`maglevgen.Carriage`)."""
    from maglevgen import api

    return api.Carriage(args.params, args.overrides)


# ------------------------------------------------------------------------------------ params


def cmd_params_show(args: argparse.Namespace) -> int:
    from maglevgen.params import annotate_with_units, default_params_text, load_params

    if args.params or args.overrides:
        load_params(args.params, args.overrides)  # validate what is shown
    raw = (default_params_text().encode("utf-8") if not args.params
           else Path(args.params).read_bytes())
    if args.raw:
        sys.stdout.flush()
        sys.stdout.buffer.write(raw)
        return 0
    sys.stdout.write(annotate_with_units(raw.decode("utf-8")))
    return 0


def cmd_params_schema(args: argparse.Namespace) -> int:
    from maglevgen.params import schema_table

    rows = schema_table()
    width = max(len(r[0]) for r in rows)
    for key, unit, desc, paper, allowed in rows:
        tail = f"  (paper: {paper})" if paper else ""
        print(f"{key:<{width}}  [{unit}]  {desc}{tail}; {allowed}")
    return 0


# -------------------------------------------------------------------------------------- trim


def cmd_trim(args: argparse.Namespace) -> int:
    carriage = _carriage(args)
    trim = carriage.trim(args.speed, acceleration=args.acceleration)
    entry, verdicts = carriage.verdicts()
    rep = {**trim.report, "envelope": entry}
    if args.json:
        print(json.dumps(rep, indent=2, sort_keys=False))
        return 0
    a = rep["acceleration"]
    moving = f" accelerating at {a:g} m/s^2 (d'Alembert load -m a at the CG)" if a else ""
    print("\n".join(verdicts) + "\n")
    print(f"Trim at {rep['speed']:g} m/s{moving} (lift-off at {rep['lift_off_speed']:.3f} "
          f"m/s; residual {rep['residual']:.2e})")
    for s in cv.STATES:  # |value| below 1e-12 (SI) is the Newton solve's round-off of a zero
        v = rep["state"][s.name]
        print(f"  {s.name:>6} = {v if abs(v) >= 1e-12 else 0.0:>13.7g} {s.unit:<6} "
              f"{s.description}")
    print(f"  F_prop = {rep['propulsion_force']:>13.7g} N      propulsion balancing the drag"
          + (f" and m a = {carriage.params.vehicle.mass * a:.6g} N" if a else ""))
    print("\nArray   gap [mm]   lift [N]   drag [N]")
    for n, a in rep["arrays"].items():
        print(f"  {n:>4} {a['gap'] * 1e3:9.4f} {a['lift']:10.4f} {a['drag']:10.4f}")
    print("\nStiffness (eqs 13-19)  derived K_st0   +gravity/prop   paper (printed)"
          "           paper/K_st0 - 1")
    for axis, r in rep["stiffness"].items():
        print(f"  {axis:<9} {r['unit']:<8} {r['derived']:12.5g} {r['derived_with_gravity']:14.5g}"
              f"   {r['paper']:10.5g} = {r['paper_formula']:<22} "
              f"{r['paper_relative_difference']:+.1%}")
    print("\nThe printed forms ignore the 45-degree tilt of arrays 1, 2, 4, 5 (their vertical "
          "components and the\nroll arm of their normals), the lower arrays in the vertical "
          "stiffness, and the moment arms of\nthe upper arrays in pitch; derive/linearize.py "
          "derives them from the geometry.")
    return 0


# ------------------------------------------------------------------------------------- gains


def cmd_gains(args: argparse.Namespace) -> int:
    from maglevgen.analyses import queries

    carriage = _carriage(args)
    report = carriage.gains_report(args.speed)
    entry, verdicts = carriage.verdicts()
    rep = {**report, "envelope": entry}
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    print("\n".join(verdicts) + "\n")
    q, r = rep["Q"], rep["R"]
    print(f"Per-axis LQR at {rep['speed']:g} m/s, Q = diag({q[0][0]:g}, {q[1][1]:g}), "
          f"R = {r:g}; u = -K (position, rate)")
    print(f"  {'axis':<9}{'k':>12}{'m':>10}{'K1 (closed)':>14}{'K2 (closed)':>13}"
          f"{'K numerical':>26}{'K paper eq 32':>26}  more accurate")
    axes = list(rep["axes"].values())
    # each column in one notation (infrastructure.columns): no 0.000223524 above 2.96472e-05
    columns = [fcolumn_plain([a["stiffness"] for a in axes], 5),
               fcolumn_plain([a["inertia"] for a in axes], 4),
               *(fcolumn_plain([a[key][i] for a in axes], 6)
                 for key in ("K_closed_form", "K_numerical", "K_paper") for i in (0, 1))]
    widths = (12, 10, 14, 13, 13, 13, 13, 13)
    for row, (axis, a) in enumerate(rep["axes"].items()):
        acc = a["accuracy_vs_50_digit_reference"]
        cells = "".join(f"{col[row]:>{w}}" for col, w in zip(columns, widths, strict=True))
        print(f"  {axis:<9}{cells}  {acc['more_accurate'].replace('_', ' ')} (error "
              f"{acc['closed_form']:.2g} vs {acc['numerical']:.2g})")
    print("  (k and K1 in N/m for lateral and vertical, N m/rad for roll, pitch and yaw; m in kg "
          "or kg m^2;\n   K2 in N s/m or N m s/rad; the last column: each gain's largest "
          "relative error against the 50-digit reference)")
    c = rep["coupled"]
    cost = {k: "unbounded (unstable)" if c[k] is None else f"{c[k]:.6g}"
            for k in ("cost_per_axis_design", "cost_coupled_lqr")}
    print(f"\nOn the coupled 10-state linearisation: cost of the per-axis design "
          f"{cost['cost_per_axis_design']}, of the coupled LQR {cost['cost_coupled_lqr']}; "
          f"slowest poles {max(p[0] for p in c['poles_per_axis_design']):.4g} and "
          f"{max(p[0] for p in c['poles_coupled_lqr']):.4g} 1/s")
    print("The paper's eq 31-32 gain (K1 = (k^2 + 1)^(1/2) - 1) is not the LQR gain: its P does "
          "not solve eq 30.")
    e = rep["embedded"]
    print(f"\nEmbedded controller ({e['title']}, `{e['controller']}`) at {e['speed']:g} m/s: "
          "u_gen = -(K_pos (a - a_ref) + K_rate a'), rows "
          f"{', '.join(e['forces'])} (N, N, N m, N m, N m), columns {', '.join(e['axes'])} "
          "(m, m, rad, rad, rad; per second for K_rate)")
    for label, K in (("K_pos", e["K_pos"]), ("K_rate", e["K_rate"])):
        print(f"  {label}:")  # round-off of a zero printed as 0 (queries.GAIN_ROUNDOFF)
        for name, row in zip(e["forces"], queries.displayed_gains(K), strict=True):
            print(f"    {name:<8}" + "".join(f"{v:12.4g}" for v in row))
    if "weights" in e:
        w = e["weights"]
        print(f"  weights (design damping ratio {w['design_damping_ratio']:g}): "
              + "; ".join(f"{a} q1 {q1:.4g}, q2 {q2:.4g}, r {r:.4g}" for a, q1, q2, r in
                          zip(e["axes"], w["q1"], w["q2"], w["r"], strict=True)))
    return 0


# ---------------------------------------------------------------------------------- envelope


def cmd_envelope(args: argparse.Namespace) -> int:
    carriage = _carriage(args)
    env = carriage.envelope(args.speeds, args.out or None, progress=True)
    if args.json:
        print(json.dumps(env.report, indent=1))
        return 0
    print("\n".join(env.lines))
    print("Ten-state closed loop (y z phi theta psi v w p q r) at the trim at each of "
          f"{env.speeds.size} speeds; x drops out, the speed is held by the propulsion.")
    if args.out:
        print(f"wrote {len(env.paths)} files to {shown_name(Path(args.out).resolve())}")
    return 0


# ---------------------------------------------------------------------------------- roa


def cmd_roa(args: argparse.Namespace) -> int:
    carriage = _carriage(args)
    res = carriage.roa(args.speeds, args.controller, args.samples, args.seed, args.workers,
                       args.batch, args.out, progress=True)
    if args.json:
        print(json.dumps(res.report, indent=1))
        return 0
    print("\n".join(res.lines))
    if args.out:
        print(f"wrote {len(res.paths)} files to {shown_name(Path(args.out).resolve())}")
    return 0


# ---------------------------------------------------------------------------------- generate


def cmd_generate(args: argparse.Namespace) -> int:
    from maglevgen.codegen.generate import GenerateOptions

    opts = GenerateOptions(args.precision, args.parameters, args.int, args.single_file)
    carriage = _carriage(args)
    _announce(f"generate: deriving and writing the C ({opts.command})")
    paths = carriage.generate(args.out, opts.precision, opts.parameters, opts.int_type,
                                     opts.single_file)
    print(f"wrote {len(paths)} files to {shown_name(Path(args.out).resolve())} ({opts.command})")
    for path in paths:
        print(f"  {path.name}")
    return 0


# ---------------------------------------------------------------------------------- firmware


def cmd_firmware(args: argparse.Namespace) -> int:
    carriage = _carriage(args)
    _announce(f"firmware: the embedded controller "
              f"{carriage.params.envelope.embedded_controller!r}'s C, its gain table and "
              f"the checks of the folder ({args.precision} precision)")
    paths = carriage.firmware(args.out, args.precision, args.with_plant, args.allow_unstable)
    print(f"wrote {len(paths)} files to {shown_name(Path(args.out).resolve())} "
          "(the embedded controller "
          f"{carriage.params.envelope.embedded_controller!r}, {args.precision} precision; "
          "what to call when: README.md there)")
    for path in paths:
        print(f"  {path.name}")
    return 0


# ---------------------------------------------------------------------------------- simulate


def cmd_simulate(args: argparse.Namespace) -> int:
    runs = _carriage(args).simulations(args.controller, args.scenario, args.speed, args.t_end,
                                       args.dt, args.loop, args.disturbance, args.check,
                                       args.out, progress=True)
    if runs.scenario == "launch":  # each run ends at release (v_max), contact or its bound
        what = (f"the launch from {runs.speed:.4g} to {runs.release_speed:.4g} m/s, each run "
                "until release, contact or divergence,")
    else:
        what = f"{args.t_end:g} s of hold"
    print(f"Simulated {what} at dt = {args.dt:g} s (RK4 in the generated C; stability limit "
          f"{runs.dt_limit:.3g} s) from trim at {runs.speed:g} m/s, F_prop = "
          f"{runs.propulsion_force:.4g} N")
    for run in runs.runs.values():  # the time each run actually reached
        print(f"  {run.controller:<8} {run.status}{': ' + run.event if run.event else ''}"
              f" (ran to t = {float(run.t[-1]):.4g} s)")
        if run.specification is not None:
            print(f"  {'':<8} specification: {run.specification}")
    for run in runs.runs.values() if args.check else ():
        if run.check is None:
            continue
        state, worst = max(run.check.items(), key=lambda kv: kv[1]["relative_to_peak"])
        print(f"  check {run.controller:<8} largest deviation from the adaptive reference: "
              f"{state} {worst['max_abs']:.3g} ({worst['relative_to_peak']:.2g} of its peak)")
    print(f"wrote {len(runs.paths)} files to {shown_name(Path(args.out).resolve())} "
          "(metrics.md: the "
          "tables)")
    return 0


# -------------------------------------------------------------------------------- montecarlo


def cmd_montecarlo(args: argparse.Namespace) -> int:
    carriage = _carriage(args)
    res = carriage.montecarlo(args.samples, args.seed, args.controller, args.t_end,
                                     args.dt, args.workers, args.scheduler, args.out or None,
                                     args.loop, progress=True, redesign=args.redesign)
    if args.json:
        print(json.dumps(res.summary, indent=1))
    else:
        t = res.summary["timing"]
        print(f"{args.samples} samples x {len(res.summary['controllers'])} controller(s): "
              f"{t['runs']} runs in {t['seconds']:.3g} s ({t['runs_per_s']:.4g} runs/s, "
              f"{t['workers']}); controller {res.summary['controller_design']}")
        for c, a in res.summary["controllers"].items():
            lo, hi = a["contact_ci95"]
            p = a["contact_probability"]
            rate = "no run" if p is None else f"{p:.4f} (95 % CI [{lo:.4f}, {hi:.4f}])"
            counts = ", ".join(f"{s} {n}" for s, n in a["status_counts"].items() if n)
            print(f"  {c:<8} contact probability {rate}; {counts}")
    if args.out:
        print(f"wrote {len(res.paths)} files to {shown_name(Path(args.out).resolve())} "
              "(montecarlo.md)",
              file=sys.stderr if args.json else sys.stdout)
    return 0


# --------------------------------------------------------------------------------------- fmu


def cmd_fmu(args: argparse.Namespace) -> int:
    from maglevgen.exports.fmu import FMI_VERSIONS, default_loop

    carriage = _carriage(args)
    _announce(f"fmu: FMI {FMI_VERSIONS[args.fmi].label} {args.kind} FMU, compiled and checked")
    path = carriage.fmu(args.out, args.kind, args.controller, args.fmi, args.loop,
                        progress=True, allow_unstable=args.allow_unstable)
    controller = args.controller or carriage.params.envelope.embedded_controller
    loop = args.loop or default_loop(carriage.params, controller)
    print(f"wrote {shown_name(path.resolve())} (FMI {FMI_VERSIONS[args.fmi].label}, {args.kind}, "
          f"controller {controller}, {loop} loop, {path.stat().st_size} bytes)")
    return 0


# ------------------------------------------------------------------------------------ report


def cmd_report(args: argparse.Namespace) -> int:
    res = _carriage(args).report(args.out, args.simulation, progress=True)
    built = f", PDF by {res.latex_tool} in {res.latex_seconds:.1f} s" if res.pdf else ""
    print(f"wrote {len(res)} files to {shown_name(res.out_dir)}{built}")
    for path in res:
        print(f"  {path.name}")
    return 0


# ------------------------------------------------------------------------------------- build


def cmd_build(args: argparse.Namespace) -> int:
    # not through maglevgen.Carriage: an up-to-date folder answers without numpy or the schema
    from maglevgen.build import BuildOptions, build_folder
    from maglevgen.infrastructure import progress

    opts = BuildOptions(t_end=args.t_end, dt=args.dt, pdf=not args.no_pdf,
                        allow_unstable=args.allow_unstable)
    res = build_folder(args.params, args.overrides, Path(args.out), opts, args.controller,
                       step=progress.step, bar=progress.bar)
    if not res.rebuilt:
        sys.stdout.write(res.verdicts())
        print(f"\n{shown_name(res.out_dir)} is up to date ({len(res.files)} files; nothing "
              "regenerated; the rest in SUMMARY.md there)")
    else:
        sys.stdout.write(res.summary)
        print(f"\nwrote {len(res.files)} files to {shown_name(res.out_dir)}:")
        for sub in ("c", "lib", "simulation", "envelope", "report"):
            print(f"  {shown_name(res.out_dir / sub)}/")
        print(f"  {shown_name(res.out_dir / 'SUMMARY.md')} (this summary)")
    for message in res.warnings(opts.allow_unstable):
        print(f"maglevgen: warning: {message}", file=sys.stderr)
    if (error := res.failure(opts.allow_unstable)) is not None:
        raise error
    return 0


# ---------------------------------------------------------------------------------- main


def _announce(message: str) -> None:
    """A command's first progress line, once its options are checked (the heartbeat then
    follows it while nothing else is said)."""
    from maglevgen.infrastructure import progress

    progress.announce(message)


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's one-line errors: the message and where to read the usage
    (no usage block), exit 2; the subcommands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"maglevgen: error: {' '.join(message.split())} "
                         f"(see `{self.prog} --help`)\n")
        sys.exit(2)


class _Controllers:
    """The registry's controller names as argparse choices, read when argparse first asks (a
    command line without --controller imports neither the registry nor numpy; the options
    give a metavar, so that add_argument does not list the choices)."""

    def __init__(self, embeddable_only: bool = False, extra: tuple[str, ...] = ()) -> None:
        self.embeddable_only, self.extra = embeddable_only, extra

    def _names(self) -> tuple[str, ...]:
        from maglevgen import controllers

        return ((controllers.embeddable() if self.embeddable_only else controllers.names())
                + self.extra)

    def __iter__(self):
        return iter(self._names())

    def __contains__(self, name: object) -> bool:
        return name in self._names()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="maglevgen",
        description="Inductrack maglev carriage: symbolic dynamics and control, generated C.")
    parser.add_argument("--version", action="version", version=f"maglevgen {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    params = sub.add_parser("params", help="show the parameter file and its schema")
    psub = params.add_subparsers(dest="params_command", required=True)
    show = psub.add_parser("show", help="print the parameter file with each key's unit")
    _common(show)
    show.add_argument("--raw", action="store_true", help="print the file exactly as stored")
    show.set_defaults(func=cmd_params_show)
    schema = psub.add_parser("schema", help="list every key with its unit and meaning")
    schema.add_argument("--debug", action="store_true")
    schema.set_defaults(func=cmd_params_schema)

    trim = sub.add_parser("trim", help="equilibrium, array gaps and forces, stiffness table")
    _common(trim)
    trim.add_argument("--speed", type=float, help="forward speed [m/s] (default: the file's)")
    trim.add_argument("--acceleration", type=float, default=0.0,
                      help="along-track acceleration [m/s^2] (default 0: constant speed): the "
                      "accelerating trim, d'Alembert load -m a at the CG, F_prop = drag + m a")
    trim.add_argument("--json", action="store_true", help="machine-readable output")
    trim.set_defaults(func=cmd_trim)

    gains = sub.add_parser("gains", help="per-axis LQR in closed form vs numerical and paper")
    _common(gains)
    gains.add_argument("--speed", type=float, help="forward speed [m/s] (default: the file's)")
    gains.add_argument("--json", action="store_true", help="machine-readable output")
    gains.set_defaults(func=cmd_gains)

    gen = sub.add_parser("generate", help="generate C for the dynamics and controllers")
    _common(gen)
    gen.add_argument("--precision", choices=("double", "single"), default="double")
    gen.add_argument("--parameters", choices=("baked", "runtime"), default="baked",
                     help="fold the parameter values in, or take them as an input vector p")
    gen.add_argument("--int", choices=("int64", "int32"), default="int64",
                     help="casadi_int: int64 (long long, as casadi.external expects) or int32 "
                          "(int, for 32-bit MCUs)")
    gen.add_argument("--single-file", action="store_true",
                     help="one translation unit (maglev.c) with only the headers' API external")
    gen.add_argument("--out", default="generated", metavar="DIR",
                     help="output folder (default: ./generated)")
    gen.set_defaults(func=cmd_generate)

    fw = sub.add_parser("firmware", help="the embedded controller's firmware folder: tick, "
                        "table schedule, main.c, CMake with a Cortex-M4F toolchain file")
    _common(fw)
    fw.add_argument("--precision", choices=("single", "double"), default="single",
                    help="single for the board (default); double to check the same code on a "
                    "host")
    fw.add_argument("--with-plant", action="store_true",
                    help="also maglev_dynamics in maglev_functions.c: the plant in the same "
                    "image for a closed loop on the target (HIL/SIL, QEMU)")
    fw.add_argument("--out", default="firmware", metavar="DIR",
                    help="output folder (default: ./firmware)")
    fw.add_argument("--allow-unstable", action="store_true",
                    help="write the folder (its README and manifest saying so) even when the "
                    "embedded controller fails the check `build` exits 3 on; without it "
                    "nothing is written and the exit code is 3")
    fw.set_defaults(func=cmd_firmware)

    sim = sub.add_parser("simulate", help="closed-loop runs of figs 3-8 in the generated C")
    _common(sim)
    sim.add_argument("--controller", choices=_Controllers(extra=("all",)), default="all",
                     metavar="NAME")
    sim.add_argument("--scenario", choices=("hold", "launch"), default="hold",
                     help="hold: the trim drag at one speed (default); launch: accelerate from "
                          "envelope.v_min to v_max with the gains scheduled in the C loop")
    _run_options(sim)
    sim.add_argument("--speed", type=float, help="forward speed [m/s] (default: the file's)")
    sim.add_argument("--disturbance", metavar="STATE=VALUE", action="append", default=[],
                     help="initial deviation of a state from trim (repeatable; given: only "
                          "these, default: 1 mm / 2 mrad on each axis)")
    sim.add_argument("--out", default="build/simulation", metavar="DIR",
                     help="output folder (default: ./build/simulation)")
    _loop_option(sim)
    sim.add_argument("--check", action="store_true",
                     help="also integrate each run with scipy's adaptive DOP853 on the SymPy "
                          "model and report the largest deviation (slow: seconds per run)")
    sim.set_defaults(func=cmd_simulate)

    mc = sub.add_parser("montecarlo", help="Monte-Carlo robustness over the file's "
                                           "[tolerances]: batch runs in the C, local or Dask")
    _common(mc)
    mc.add_argument("--samples", type=int, default=1000, metavar="N",
                    help="samples to draw (default 1000)")
    mc.add_argument("--seed", type=int, default=0, metavar="S",
                    help="seed; sample i draws from SeedSequence(S, spawn_key=(i,)) (default 0)")
    mc.add_argument("--controller", choices=_Controllers(extra=("all",)), metavar="NAME",
                    help="default: envelope.embedded_controller")
    _run_options(mc)
    _loop_option(mc)
    mc.add_argument("--redesign", action="store_true",
                    help="re-design the controller for each sample's own parameters, as if "
                         "the firmware knew them (default: the nominal design, as the "
                         "firmware flies)")
    mc.add_argument("--workers", type=int, metavar="K",
                    help="worker processes (default: every core); with --scheduler local, "
                         "the LocalCluster's workers")
    mc.add_argument("--scheduler", metavar="ADDRESS",
                    help="run the chunks on Dask: tcp://HOST:PORT of a running scheduler, or "
                         "'local' for a LocalCluster")
    mc.add_argument("--out", metavar="DIR", default="build/montecarlo",
                    help="output folder (default: ./build/montecarlo)")
    mc.add_argument("--json", action="store_true", help="print montecarlo.json on stdout")
    mc.set_defaults(func=cmd_montecarlo)

    env = sub.add_parser("envelope", help="closed-loop stability of each controller across "
                                          "the speed envelope, with verdicts")
    _common(env)
    env.add_argument("--speeds", type=int, default=None, metavar="N",
                     help="speeds spanning [v_min, v_max] (default 50)")
    env.add_argument("--json", action="store_true", help="machine-readable output")
    env.add_argument("--out", metavar="DIR",
                     help="also write envelope.json, envelope.md and stability_map.png")
    env.set_defaults(func=cmd_envelope)

    roa = sub.add_parser("roa", help="a sampled region of attraction of the controller per "
                                     "speed (V = x'Px, dV/dt < 0 on the nonlinear loop in C, "
                                     "boundary runs as the firmware flies: on the "
                                     "sensors for the embedded controller)")
    _common(roa)
    roa.add_argument("--speeds", type=int, default=None, metavar="N",
                     help="speeds spanning [v_min, v_max] (default 8)")
    roa.add_argument("--controller", default=None, metavar="NAME",
                     help="a registered controller or 'all' (default: "
                          "envelope.embedded_controller)")
    roa.add_argument("--samples", type=int, default=None, metavar="M",
                     help="random directions on the ellipsoid per speed (default 3000)")
    roa.add_argument("--seed", type=int, default=0, help="seed of the directions (default 0)")
    roa.add_argument("--workers", type=int, default=1, metavar="K",
                     help="threads evaluating the batches (default 1; the numbers do not "
                          "change)")
    roa.add_argument("--batch", type=int, default=None, metavar="B",
                     help="states per C call (default 8192; the numbers do not change)")
    roa.add_argument("--json", action="store_true", help="print roa.json on stdout")
    roa.add_argument("--out", metavar="DIR",
                     help="also write roa.json, roa.md and roa_extent.png")
    roa.set_defaults(func=cmd_roa)
    from maglevgen.exports.fmu import DEFAULT_FMI, FMI_VERSIONS, FMU_LOOPS
    from maglevgen.exports.fmu import KINDS as FMU_KINDS

    fmu = sub.add_parser("fmu", help="FMI 2.0 or 3.0 FMU (model exchange, co-simulation) of the "
                                     "carriage")
    _common(fmu)
    fmu.add_argument("--kind", choices=FMU_KINDS, default="both",
                     help="model exchange, co-simulation or both (default)")
    fmu.add_argument("--controller", choices=_Controllers(extra=("external",)), metavar="NAME",
                     help="controller inside the FMU, or 'external': the generalized control "
                          "forces are inputs (default: envelope.embedded_controller, the one "
                          "the firmware embeds)")
    fmu.add_argument("--fmi", choices=tuple(FMI_VERSIONS), default=DEFAULT_FMI,
                     help="FMI version: 2 (2.0, the default: every importer reads it) or 3 "
                          "(3.0); the same variables, controllers and start values")
    fmu.add_argument("--loop", choices=FMU_LOOPS, default=None,
                     help="sensed (default for the embedded controller where the file has "
                          "[sensors]): the firmware's sense tick inside the FMU on the plant's "
                          "noisy readings (noise_seed, noise_scale, sensor.*); "
                          "firmware (the default otherwise): the loop as built on the exact "
                          "state, as `simulate --loop "
                          "firmware` flies it: the built-in controller's tick law at the tick "
                          "of [control.spec] with its delay and design gains, the speed loop "
                          "and its integral, the force budget, each array force's lag in the "
                          "plant (the start values of tick_rate, delay_ticks, speed_gain, "
                          "force_budget, actuator_lag, speed_integral, K_lag, K_delay); "
                          "continuous: the paper's law at every derivative evaluation")
    fmu.add_argument("--out", default="build/fmu", metavar="DIR",
                     help="output folder of maglev.fmu (default: ./build/fmu)")
    fmu.add_argument("--allow-unstable", action="store_true",
                     help="write the FMU of the embedded controller (its description saying "
                     "so) even when it fails the check `build` exits 3 on; without it nothing "
                     "is written and the exit code is 3")
    fmu.set_defaults(func=cmd_fmu)

    bld = sub.add_parser("build", help="the main job: C, library, simulations and report, "
                                       "brought up to date in one atomic step")
    _common(bld)
    bld.add_argument("--out", default="build", metavar="DIR",
                     help="output folder (default: ./build)")
    _run_options(bld)
    bld.add_argument("--no-pdf", action="store_true", help="write report.tex only")
    bld.add_argument("--controller", choices=_Controllers(embeddable_only=True), metavar="NAME",
                     help="the controller the firmware C embeds and the build verifies "
                          "(default: envelope.embedded_controller, the spec design)")
    bld.add_argument("--allow-unstable", action="store_true",
                     help="exit 0 with a warning (not 3) when the embedded controller is "
                          "unstable somewhere in the envelope or fails a spec of "
                          "[control.spec] (the linear verdict or a hold or launch run)")
    bld.set_defaults(func=cmd_build)

    rep = sub.add_parser("report", help="LaTeX derivation report, and its PDF where TeX is "
                                        "installed")
    _common(rep)
    rep.add_argument("--out", default="report", metavar="DIR",
                     help="output folder (default: ./report)")
    rep.add_argument("--simulation", metavar="DIR",
                     help="folder written by `maglevgen simulate --out`: include its figures")
    rep.set_defaults(func=cmd_report)
    return parser


def _json_default(o: object) -> object:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(type(o))


def main(argv: Sequence[str] | None = None) -> int:
    from maglevgen.infrastructure.cache import STORE
    from maglevgen.infrastructure.progress import heartbeat, step

    parser = build_parser()
    args = parser.parse_args(argv)
    STORE.progress = step  # announce derivation steps that are not cached yet
    func: Callable[[argparse.Namespace], int] = args.func
    debug = getattr(args, "debug", False)
    try:
        with heartbeat(), warnings.catch_warnings():
            if not debug:
                # numpy's floating-point warnings (overflow in an extreme but valid carriage,
                # whose outcome is checked and reported) and SciPy's: the command reports
                # what matters in its own words
                warnings.simplefilter("ignore")
            return func(args)
    except MaglevError as exc:
        if debug:
            details = getattr(exc, "details", None)
            if details:
                print(f"maglevgen: {details}", file=sys.stderr)
            raise
        print(f"maglevgen: error: {one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("maglevgen: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        _reader_gone()
        return 0
    except OSError as exc:
        if debug:
            raise
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):  # a full disk anywhere: as --out's
            where = f" to {exc.filename}" if exc.filename else ""
            print(f"maglevgen: error: cannot write{where}: {exc.strerror}", file=sys.stderr)
            return 2
        print(f"maglevgen: internal error: {type(exc).__name__}: {one_line(exc)} "
              "(rerun with --debug)", file=sys.stderr)
        return 1
    except Exception as exc:  # internal failure: one line unless --debug
        if debug:
            raise
        print(f"maglevgen: internal error: {type(exc).__name__}: {one_line(exc)} "
              "(rerun with --debug)", file=sys.stderr)
        return 1


def one_line(exc: BaseException) -> str:
    """An error's message on one line, whatever the library that wrote it put in it, with
    any control character left in it (a user's file name) escaped for the terminal."""
    return shown_name(" ".join(str(exc).split()))


def run() -> None:
    """The console entry point: `main`, its exit code, and a normal interpreter exit
    (atexit handlers and buffered output included).

    `gc.freeze` first: the interpreter's final garbage collection then skips the objects
    alive at exit (SymPy's caches and expression graphs: about 0.6 s of a rebuild's 5 s,
    bench/experiments/paired_rebuild.py); their memory goes back with the process.
    """
    code = main()
    gc.freeze()
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _reader_gone()
    except ValueError:  # a closed stream
        pass
    sys.exit(code)


def _reader_gone() -> None:
    """The reader of stdout went away (`| head`): nothing left to say to it. Python's recipe
    (the signal module's "Note on SIGPIPE"): stdout goes to devnull for the exit's flush."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


if __name__ == "__main__":
    run()
