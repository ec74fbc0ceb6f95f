"""Where a Monte-Carlo sample's CPU goes (issue 53): `maglevgen montecarlo`'s default study
(the embedded controller, 10 s at 1 kHz, seed 0) on ``--loop sensed`` (the default: the
firmware's sense tick on noisy readings) and ``--loop firmware`` (the exact state).

    .venv/bin/python bench/experiments/sample_cost.py [--samples N] [--loops sensed firmware]
        [--profile]

Per loop, on one process (`run_local`, workers=1: the study's own chunks, one thread): the CPU
per sample of the whole study (draws, trims, gains, the C batch, metrics) and of the bare C
batch alone on the same prepared runs (`simulate_batch` in the study's chunks, lanes as the
study picks them, and the scalar driver; each sensed run's noise drawn again, outside the
timing), so the Python's share is their difference;
``--profile``: cProfile's top functions of the study by cumulative and by own time.
CPU time of this process (time.process_time); one round: the machine is shared, take the
ratios, not the seconds.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common import log, study_runs

from maglevgen.analyses.montecarlo import default_chunk, make_study, run_local
from maglevgen.analyses.simulate import run_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.params import load_params

T_END, DT = 10.0, 1e-3


def measure(loop: str, n: int, profile: bool) -> dict:
    carriage = DerivedCarriage(load_params())
    plant = Plant(carriage)
    lib = plant.lib
    controller = carriage.params.envelope.embedded_controller
    study = make_study(plant, (controller,), T_END, DT, 0, *run_loop(plant, loop))
    run_local(study, 2, workers=1)  # warm: the library, the driver, the firmware
    t0 = time.process_time()
    run_local(study, n, workers=1)
    whole = (time.process_time() - t0) / n
    t0 = time.process_time()
    runs, n_u, n_g = study_runs(study, lib, n)
    prepare = (time.process_time() - t0) / n
    n_steps = round(T_END / DT)
    size = default_chunk(n, 1)  # the study's own chunks
    out = {"loop": loop, "samples": n, "chunk": size, "study_s": whole, "prepare_s": prepare}
    for name, lanes in (("lanes", 0), ("scalar", None)):
        runs, n_u, n_g = study_runs(study, lib, n)  # afresh: a sensed run's state is its own
        t0 = time.process_time()
        for i in range(0, len(runs), size):
            lib.simulate_batch(runs[i:i + size], DT, n_steps, study.min_gap, n_u, n_g, 1,
                               lanes=lanes)
        out[f"bare_{name}_s"] = (time.process_time() - t0) / len(runs)
    if profile:
        pr = cProfile.Profile()
        pr.enable()
        run_local(study, n, workers=1)
        pr.disable()
        for key in ("cumulative", "tottime"):
            s = io.StringIO()
            pstats.Stats(pr, stream=s).sort_stats(key).print_stats(25)
            out[f"profile_{key}"] = s.getvalue()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--loops", nargs="+", default=["sensed", "firmware"])
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    results = []
    for loop in args.loops:
        log(f"sample_cost: --loop {loop}, {args.samples} samples")
        r = measure(loop, args.samples, args.profile)
        results.append(r)
        print(f"{loop}: study {r['study_s'] * 1e3:.1f} ms/sample; bare C lanes "
              f"{r['bare_lanes_s'] * 1e3:.1f} ms, scalar {r['bare_scalar_s'] * 1e3:.1f} ms; "
              f"prepare (draws, trims, gains) {r['prepare_s'] * 1e3:.1f} ms")
        for key in ("profile_cumulative", "profile_tottime"):
            if key in r:
                print(r[key])
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
