"""The judged runs against every sign combination of the default disturbance
(maglevgen.analyses.worst_case, what `build` judges the launch and the holds on).

References: the 32 combinations written out here from the bits of 0..31; a brute force of
the launch through the public API (`Carriage.simulate`, one run per combination with its
disturbance given explicitly), each run's smallest gap read from its gaps.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevgen.analyses.run_spec import RunCheck, RunVerdict
from maglevgen.analyses.simulate import DISTURBANCE, run_scenarios, spec_verdict
from maglevgen.analyses.worst_case import sign_combinations, signs_text, worst_verdict
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant


def test_every_sign_combination_once() -> None:
    keys = [k for k, v in DISTURBANCE.items() if v != 0.0]
    expected = {tuple((-1) ** ((n >> i) & 1) * DISTURBANCE[k] for i, k in enumerate(keys))
                for n in range(2 ** len(keys))}
    combos = sign_combinations(DISTURBANCE)
    assert len(combos) == 32 == len(expected)
    assert {tuple(d[k] for k in keys) for d in combos} == expected
    assert combos[0] == DISTURBANCE  # the given signs first
    assert signs_text({"y": 1e-3, "z": -1e-3, "x": 0.0}) == "y+ z-"


def test_the_worst_check_names_its_combination() -> None:
    """Planted: three runs whose gap margins and peaks differ; the verdict takes the
    smallest margin and the largest peak, each from its own run, and fails on the margin."""
    def verdict(margin: float, peak: float) -> RunVerdict:
        return RunVerdict((RunCheck("peak lateral deviation", peak, 2e-3, "m", peak <= 2e-3),
                           RunCheck("smallest gap margin", margin, 3e-3, "m", margin >= 3e-3),
                           RunCheck("time at the force budget", 0.01, None, "s", None)))
    a, b, c = ({"y": 1e-3, "z": 1e-3}, {"y": -1e-3, "z": 1e-3}, {"y": 1e-3, "z": -1e-3})
    v = worst_verdict([(a, verdict(4e-3, 1.0e-3)), (b, verdict(2.5e-3, 1.1e-3)),
                       (c, verdict(3.5e-3, 1.5e-3))])
    peak, margin, _ = v.checks
    assert margin.value == 2.5e-3 and margin.ok is False and "y- z+" in margin.note
    assert peak.value == 1.5e-3 and peak.ok is True and "y+ z-" in peak.note
    assert not v.meets and v.text().startswith("FAILS smallest gap margin")


@pytest.mark.slow
def test_worst_launch_against_a_brute_force_of_all_32(carriage, sim_lib) -> None:
    """The launch verdict `build` judges (run_scenarios over sign_combinations, worst_verdict)
    against 32 launches through the public API, each from its own signs: the verdict's
    smallest gap margin is the brute force's smallest, the combination it names has that
    margin, and the verdict fails exactly when that margin is below control.spec's."""
    import maglevgen

    spec = carriage.params.control.spec
    min_gap = carriage.params.track.min_gap
    name = carriage.params.envelope.embedded_controller
    combos = sign_combinations(DISTURBANCE)
    sim = run_scenarios(Plant(carriage, sim_lib), (name,), 10.0, 1e-3, scenario="launch",
                        loop=Loop.FIRMWARE, disturbances=combos)
    v = worst_verdict([(d, spec_verdict(t)) for d, t in zip(combos, sim.trajectories,
                                                             strict=True)])
    (gap,) = [c for c in v.checks if c.name == "smallest gap margin"]

    api = maglevgen.load()
    keys = [k for k, x in DISTURBANCE.items() if x != 0.0]
    brute = {}
    for n in range(2 ** len(keys)):
        d = {k: (-1) ** ((n >> i) & 1) * DISTURBANCE[k] for i, k in enumerate(keys)}
        run = api.simulate(controller=name, scenario="launch", disturbance=d)
        brute[signs_text(d)] = float(np.min(run.gaps)) - min_gap
    worst = min(brute.values())
    assert gap.value == pytest.approx(worst, rel=1e-12)
    named = gap.note.split("worst at ")[1]
    assert brute[named] == pytest.approx(worst, rel=1e-12)
    assert gap.ok == (worst >= spec.min_gap_margin)
    # the all-positive start alone is not the worst (the reason for the search)
    assert brute[signs_text(DISTURBANCE)] > worst
