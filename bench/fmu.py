"""The FMU of `maglevgen fmu` through FMPy against the toolchain's own runtime, in one run.

    python bench/fmu.py [--repeats N]

Co-simulation: 10 s at a 1 ms communication step (= the internal RK4 step), LQR controller,
through `fmpy.simulate_fmu` (recording every state) and through FMPy's bare FMU2Slave.doStep
loop, each paired in the same repeat with the same run in `maglev_simulate` (the compiled
library `maglevgen simulate` calls). Model exchange: FMPy's CVode against scipy solve_ivp
(DOP853) on the lambdified SymPy model, both at rtol 1e-8, 2 s. Writes bench/fmu_results.json
and the FMU section of BENCHMARKS.md (writeup.py renders the same section in a full run).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import BENCH, log, paired_ratios, replace_section, summary

from maglevgen.analyses.reference import reference_trajectory
from maglevgen.analyses.simulate import DISTURBANCE, initial_state
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import build_fmu
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

RESULTS = BENCH / "fmu_results.json"
CS_T_END, DT = 10.0, 1e-3
ME_T_END, ME_RTOL = 2.0, 1e-8
BEGIN, END = "<!-- fmu benchmark: bench/fmu.py -->", "<!-- end of fmu benchmark -->"


def measure(repeats: int) -> dict:
    from fmpy import extract, read_model_description, simulate_fmu
    from fmpy.fmi2 import FMU2Slave

    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    p, min_gap = carriage.p, carriage.params.track.min_gap
    plant = Plant(carriage, lib)
    (op,) = plant.points([carriage.params.operation.speed])
    k_pos, k_rate = op.gains("lqr")
    x0 = initial_state(op, DISTURBANCE)
    n_steps = round(CS_T_END / DT)
    states = [s.name for s in cv.STATES]
    with tempfile.TemporaryDirectory() as tmp:
        paths = {}
        for kind in ("cs", "me"):
            paths[kind] = Path(tmp) / f"{kind}.fmu"
            # the paper's law at every derivative evaluation, as lib.simulate and the
            # DOP853 reference run it: the same C arithmetic on both sides
            paths[kind].write_bytes(build_fmu(plant, kind, "lqr", loop=Loop.CONTINUOUS))
        md = read_model_description(str(paths["cs"]))
        unzipped = extract(str(paths["cs"]))

        def own() -> float:
            t0 = time.perf_counter()
            lib.simulate(x0, DT, n_steps, op.f_prop, k_pos, k_rate, op.a_trim, p, min_gap,
                         op.allocation.shape[0] + 1, op.gaps.size)
            return time.perf_counter() - t0

        def fmpy_simulate() -> float:
            t0 = time.perf_counter()
            simulate_fmu(unzipped, model_description=md, fmi_type="CoSimulation",
                         stop_time=CS_T_END, output_interval=DT, output=states)
            return time.perf_counter() - t0

        def fmpy_do_step() -> float:
            fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="b")
            fmu.instantiate()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            t0 = time.perf_counter()
            for k in range(n_steps):
                fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
            dt = time.perf_counter() - t0
            fmu.terminate()
            fmu.freeInstance()
            return dt

        cs = {"own": [], "simulate_fmu": [], "do_step": [], "own_b": []}
        for r in range(repeats):
            log(f"co-simulation repeat {r + 1}/{repeats}")
            cs["own"].append(own())
            cs["simulate_fmu"].append(fmpy_simulate())
            cs["own_b"].append(own())
            cs["do_step"].append(fmpy_do_step())

        t_eval = np.linspace(0.0, ME_T_END, round(ME_T_END / DT) + 1)
        me = {"cvode": [], "solve_ivp": []}
        dev = []
        for r in range(repeats):
            log(f"model exchange repeat {r + 1}/{repeats}")
            t0 = time.perf_counter()
            res = simulate_fmu(str(paths["me"]), fmi_type="ModelExchange", solver="CVode",
                               relative_tolerance=ME_RTOL, stop_time=ME_T_END,
                               output_interval=DT, output=states, record_events=False)
            me["cvode"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ref = reference_trajectory(carriage.functions, p, op, "lqr", t_eval,
                                       rtol=ME_RTOL, atol=ME_RTOL)
            me["solve_ivp"].append(time.perf_counter() - t0)
            x = np.column_stack([res[n] for n in states])
            # per state, relative to its largest magnitude over the run
            dev.append(float((np.abs(x - ref).max(axis=0) / np.abs(ref).max(axis=0).clip(
                1e-300)).max()))
    per_step = {k: [v / n_steps for v in vals] for k, vals in cs.items()}
    return {
        "cs": {
            "t_end": CS_T_END, "dt": DT, "steps": n_steps,
            "own_per_step_s": summary(per_step["own"] + per_step["own_b"]),
            "simulate_fmu_per_step_s": summary(per_step["simulate_fmu"]),
            "do_step_per_step_s": summary(per_step["do_step"]),
            "simulate_fmu_vs_own": paired_ratios(cs["simulate_fmu"], cs["own"]),
            "do_step_vs_own": paired_ratios(cs["do_step"], cs["own_b"]),
        },
        "me": {
            "t_end": ME_T_END, "rtol": ME_RTOL,
            "cvode_s": summary(me["cvode"]), "solve_ivp_s": summary(me["solve_ivp"]),
            "solve_ivp_vs_cvode": paired_ratios(me["solve_ivp"], me["cvode"]),
            "max_state_difference_relative": max(dev),
        },
        "repeats": repeats,
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
    }


def _t(s: dict, scale: float, unit: str) -> str:
    return (f"{s['median'] * scale:.3g} [{s['q1'] * scale:.3g}-{s['q3'] * scale:.3g}] {unit}")


def section(r: dict) -> list[str]:
    """The FMU section of BENCHMARKS.md."""
    cs, me = r["cs"], r["me"]
    return [
        BEGIN,
        "## 7. The FMU (`maglevgen fmu`) through FMPy",
        "",
        f"Measured by `python bench/fmu.py` ({r['repeats']} repeats, {r['date_utc']} UTC; raw "
        "figures: bench/fmu_results.json). Co-simulation FMU with the LQR inside, "
        f"{cs['t_end']:g} s at a {cs['dt'] * 1e3:g} ms communication step equal to its internal "
        "RK4 step, against the same run in `maglev_simulate` (the library `maglevgen "
        "simulate` calls), paired in each repeat; the trajectories are identical (tests/"
        "test_fmu.py).",
        "",
        "| run | time per communication step | / toolchain's runtime |",
        "| --- | --- | --- |",
        f"| toolchain's runtime (`maglev_simulate`, one C call) | "
        f"{_t(cs['own_per_step_s'], 1e6, 'us')} | 1x |",
        f"| FMPy `FMU2Slave.doStep` loop (no recording) | "
        f"{_t(cs['do_step_per_step_s'], 1e6, 'us')} | {cs['do_step_vs_own']['median']:.3g}x |",
        f"| FMPy `simulate_fmu` (records the 12 states) | "
        f"{_t(cs['simulate_fmu_per_step_s'], 1e6, 'us')} | "
        f"{cs['simulate_fmu_vs_own']['median']:.3g}x |",
        "",
        f"Model exchange, {me['t_end']:g} s at rtol {me['rtol']:g}: FMPy's CVode on the FMU "
        f"{_t(me['cvode_s'], 1, 's')}, scipy solve_ivp (DOP853) on the lambdified SymPy model "
        f"{_t(me['solve_ivp_s'], 1, 's')} ({me['solve_ivp_vs_cvode']['median']:.3g}x the "
        f"CVode run); the two differ by at most "
        f"{me['max_state_difference_relative']:.2g} of a state's largest magnitude.",
        "",
        "The FMU's step costs FMPy's Python-side call per communication step on top of the same "
        "C arithmetic; `maglev_simulate` runs the whole horizon in one call.",
        END,
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    r = measure(args.repeats)
    RESULTS.write_text(json.dumps(r, indent=1) + "\n")
    replace_section(section(r), BEGIN, END)
    log(f"wrote {RESULTS} and the FMU section of BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
