"""Adding a linear controller is one registration: a controller registered the way a module of
maglevgen/control/ registers one, after `maglevgen.load()` (the registry is read where it is
needed, never copied at import), reaches the CLI's choices, the API, the gains, the envelope,
the simulations in the firmware loop, the firmware folder and the FMU, with nothing else
edited.

The example is the optimized damping (eqs 20-21) written as a general linear law (K_pos = 0,
K_rate = diag(c)) run by the generic matrix tick (``maglev_coupled_control``) instead of the
damping's own diagonal tick: its poles and runs are checked against the registered
``damping`` controller's, which its own tests hold against independent references.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

# the tests of the example: one child process builds the FMU and verifies the firmware
# folder's controller over the envelope (about 2.5 min of CPU)
slow = pytest.mark.slow

# The module a developer would add (maglevgen/control/<name>.py), then the checks, in a child
# process: the registry of this test session stays as it is.
_CHILD = r'''
import json, sys
import numpy as np
import maglevgen
from maglevgen.controllers import Controller, register

c = maglevgen.load()  # before the controller exists

def _damping_as_matrix(op):
    return np.zeros((5, 5)), np.diag(op.c_damping)

register(Controller(
    "example", "damping as a matrix", "optimized damping through the generic linear tick",
    _damping_as_matrix, tick_function="maglev_coupled_control", fmu_gains="matrix",
    style={"color": "tab:red", "ls": "-.", "lw": 1.0}))

from maglevgen.cli import build_parser

out = {}
sim_choices = next(a for a in build_parser()._subparsers._group_actions[0].choices[
    "simulate"]._actions if a.dest == "controller").choices
out["simulate_choices"] = list(sim_choices)
g_ex, g_d = c.gains(controller="example"), c.gains(controller="damping")
out["gains"] = [g_ex.K.tolist(), g_d.K.tolist()]
out["poles"] = [sorted(map(str, np.round(np.sort_complex(g.poles), 9)))
                for g in (g_ex, g_d)]
env = c.envelope(n_speeds=5)
out["envelope"] = {n: env.max_real[n].tolist() for n in ("example", "damping")}
out["verdict"] = env.verdicts["example"]
runs = [c.simulate(controller=n, t_end=0.3) for n in ("example", "damping")]
out["runs"] = [r.x.tolist() for r in runs]
out["status"] = [r.status for r in runs]
from fmpy import simulate_fmu
fmu = c.fmu(sys.argv[1], kind="cs", controller="example")
res = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=0.3, output_interval=1e-3,
                   output=list(runs[0].state_names))
out["fmu_x"] = np.column_stack([res[s] for s in runs[0].state_names]).tolist()
# the FMU's firmware loop: the loop as built (the tick's law with the example's gains, the
# speed loop and its integral, the budget, the actuator lag), as `simulate --loop firmware`
from maglevgen.analyses.simulate import Loop, run_scenarios
out["fmu_ref"] = run_scenarios(c._plant, ("example",), 0.3, 1e-3,
                               loop=Loop.FIRMWARE).trajectories[0].x.tolist()
# the firmware folder with the example embedded (a parameter file may name it now); not
# verified against [control.spec] (the damping law is not meant to meet it)
fw = maglevgen.load(overrides=['envelope.embedded_controller="example"'])
written = fw.firmware(sys.argv[2], precision="double", allow_unstable=True)
out["firmware"] = {p.name: p.read_text() for p in written if p.suffix in (".c", ".h", ".md")}
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def example(tmp_path_factory: pytest.TempPathFactory) -> dict:
    folder = tmp_path_factory.mktemp("example_controller")
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(folder / "fmu"),
                           str(folder / "firmware")],
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.splitlines()[-1])


@slow
def test_a_registered_controller_is_a_choice_of_the_cli(example: dict) -> None:
    assert "example" in example["simulate_choices"]


@slow
def test_its_gains_and_poles_are_the_law_it_registers(example: dict) -> None:
    import numpy as np

    K_ex, K_d = (np.array(k) for k in example["gains"])
    np.testing.assert_array_equal(K_ex, K_d)
    assert example["poles"][0] == example["poles"][1]


@slow
def test_the_envelope_judges_it(example: dict) -> None:
    import numpy as np

    np.testing.assert_allclose(example["envelope"]["example"], example["envelope"]["damping"],
                               rtol=1e-9, atol=1e-12)
    assert example["verdict"]


@slow
def test_the_firmware_loop_runs_it_through_the_generic_tick(example: dict) -> None:
    """The generic matrix tick against the damping's diagonal one: the same law, so the same
    run up to the round-off of a 5 x 10 product against a diagonal one."""
    import numpy as np

    x_ex, x_d = (np.array(x) for x in example["runs"])
    assert example["status"][0] == example["status"][1]
    assert x_ex.shape == x_d.shape
    scale = np.max(np.abs(x_d), axis=0) + 1e-12
    assert np.max(np.abs(x_ex - x_d) / scale) < 1e-9


@slow
def test_the_fmu_runs_it_as_the_simulation_does(example: dict) -> None:
    """The co-simulation FMU with the example built in, under FMPy, against the host's
    firmware loop (the same RK4, lag and tick arithmetic)."""
    import numpy as np

    x_fmu, x_api = np.array(example["fmu_x"]), np.array(example["fmu_ref"])
    assert x_fmu.shape == x_api.shape
    scale = np.max(np.abs(x_api), axis=0) + 1e-12
    assert np.max(np.abs(x_fmu - x_api) / scale) < 1e-9


@slow
def test_the_firmware_folder_embeds_it(example: dict) -> None:
    """The firmware folder with ``envelope.embedded_controller = "example"``: its README names
    it, its tick calls the generic matrix tick, and its gain table stores the registered law
    (K_pos = 0, K_rate diagonal): no entry of K_pos, the five diagonal entries of K_rate."""
    import re

    from maglevgen.control.schedule import GAIN_TABLE_FIELDS

    fw = example["firmware"]
    assert "`example` (damping as a matrix)" in fw["README.md"]
    assert "maglev_coupled_control(" in fw["maglev_tick.c"]
    start, offsets = 0, {}
    for name, size in GAIN_TABLE_FIELDS:
        offsets[name], start = range(start, start + size), start + size
    # the values maglev_schedule writes (each one's Clenshaw written out:
    # out[MAGLEV_SCHEDULE_OUT_<FIELD> + k] = ...), placed by the header's field macros
    macro = {m: int(v) for m, v in re.findall(r"#define (MAGLEV_SCHEDULE_OUT_\w+) (\d+)",
                                                fw["maglev_gain_table.h"])}
    body = fw["maglev_gain_table.c"].split("int maglev_schedule(", 1)[1].split("\n}\n", 1)[0]
    stored = {macro[m] + int(k or 0) for m, k in
              re.findall(r"^\s*out\[(MAGLEV_SCHEDULE_OUT_\w+)(?: \+ (\d+))?\] = ", body,
                         re.MULTILINE)}
    assert stored
    assert macro["MAGLEV_SCHEDULE_OUT_K_RATE"] == offsets["K_rate"][0]
    n = int(len(offsets["K_rate"]) ** 0.5)
    assert not stored & set(offsets["K_pos"])
    assert stored & set(offsets["K_rate"]) == {offsets["K_rate"][i * (n + 1)] for i in range(n)}


def test_nothing_else_names_a_controller(tmp_path: Path) -> None:
    """No module outside maglevgen/control/ spells out the list of controllers (a literal
    tuple, list or set of three or more of their names): where a consumer needs them it
    iterates over the registry."""
    import ast

    from maglevgen.controllers import names

    known = set(names())
    root = Path(__file__).resolve().parents[1]

    def listings(path: Path) -> list[str]:
        return [ast.unparse(n) for n in ast.walk(ast.parse(path.read_text()))
                if isinstance(n, (ast.Tuple, ast.List, ast.Set))
                and len({e.value for e in n.elts if isinstance(e, ast.Constant)} & known) >= 3]

    found = {str(p.relative_to(root)): hits for folder in ("maglevgen", "runtime", "derive")
             for p in (root / folder).rglob("*.py")
             if "control" not in p.relative_to(root).parts and (hits := listings(p))}
    assert found == {}
    planted = tmp_path / "planted.py"  # the check itself
    planted.write_text('SHOWN = ("damping", "lqr", "coupled")\n')
    assert listings(planted) == ["('damping', 'lqr', 'coupled')"]


def test_nothing_else_compares_a_controller_name() -> None:
    """No module outside maglevgen/control/ compares a value with a registered controller's
    name (``name == "spec"``): what it branches on is a field of the `Controller`. (``loop``
    has a vocabulary of its own, in which "none" is a loop, not a controller.)"""
    import ast

    from maglevgen.controllers import names

    known = set(names())
    root = Path(__file__).resolve().parents[1]

    def comparisons(path: Path) -> list[str]:
        return [ast.unparse(n) for n in ast.walk(ast.parse(path.read_text()))
                if isinstance(n, ast.Compare)
                and not any(isinstance(e, ast.Name) and e.id == "loop"
                            for e in (n.left, *n.comparators))
                and any(isinstance(e, ast.Constant) and e.value in known
                        for e in (n.left, *n.comparators))]

    found = {str(p.relative_to(root)): hits for folder in ("maglevgen", "runtime", "derive")
             for p in (root / folder).rglob("*.py")
             if "control" not in p.relative_to(root).parts and (hits := comparisons(p))}
    assert found == {}
