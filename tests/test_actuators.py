"""The actuator models (control.actuators) and the inertia choice (vehicle.inertia_cg), against
references built here: the effectiveness matrix from the geometry written below and numpy's
Moore-Penrose pinv, scipy's least squares, and the box inertia from a SymPy triple integral of
a uniform density.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import sympy as sp

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.symbolic_reference import allocation_matrix
from maglevgen.params import load_params

NORMAL = 'control.actuators="normal"'
BOX = 'vehicle.inertia_cg="box"'

# The LLNL carriage of the default file, written out (arrays 1-6 of the paper's Fig. 2): face
# centres about O [m] and the unit normals along which the track pushes each array.
S = 1 / np.sqrt(2)
POSITIONS = np.array([[0.26, 0.09, -0.119], [0.26, -0.09, -0.119], [0.26, 0.0, -0.03],
                      [-0.26, 0.09, -0.119], [-0.26, -0.09, -0.119], [-0.26, 0.0, -0.03]])
NORMALS = np.array([[0, S, -S], [0, -S, -S], [0, 0, 1], [0, S, -S], [0, -S, -S], [0, 0, 1]])
EY, EZ = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])


def wrench(position: np.ndarray, force: np.ndarray) -> np.ndarray:
    """(F_y, F_z, M_x, M_y, M_z) about O of ``force`` acting at ``position``."""
    return np.concatenate([force[1:], np.cross(position, force)])


def effectiveness(actuators: str) -> np.ndarray:
    """E from the geometry above: eqs 22-23's body y (where the normal has a y part) and z
    forces per array, or one force along each normal."""
    cols = []
    for r, n in zip(POSITIONS, NORMALS, strict=True):
        directions = [n] if actuators == "normal" else [EY, EZ] if n[1] != 0 else [EZ]
        cols += [wrench(r, d) for d in directions]
    return np.array(cols).T


@pytest.fixture(scope="module")
def normal_carriage() -> DerivedCarriage:
    return DerivedCarriage(load_params(overrides=[NORMAL]))


@pytest.fixture(scope="module")
def normal_lib(normal_carriage, private_cache):
    from maglevgen.runtime.library import simulation_library

    return simulation_library(normal_carriage.structure)


def test_geometry_written_here_is_the_default_files(carriage) -> None:
    arrays = list(carriage.params.arrays.values())
    np.testing.assert_allclose([a.position for a in arrays], POSITIONS, rtol=0, atol=0)
    np.testing.assert_allclose([a.normal for a in arrays], NORMALS, rtol=0, atol=1e-16)


def test_input_names_follow_the_actuator_model(carriage, normal_carriage) -> None:
    assert carriage.model.input_names == ("F_prop", "F_y1", "F_z1", "F_y2", "F_z2", "F_z3",
                                          "F_y4", "F_z4", "F_y5", "F_z5", "F_z6")
    assert normal_carriage.model.input_names == ("F_prop", *(f"F_n{i}" for i in range(1, 7)))


def test_normal_actuators_leave_roll_about_the_lines_crossing_uncontrolled() -> None:
    """Six forces for five generalized forces, yet E is of rank 4: every normal's line of
    action meets the x axis at z0 = -0.119 + 0.09 m (the upper ones are vertical at y = 0), so
    the moment about that axis, M_x + z0 F_y, is zero whatever the forces."""
    E = effectiveness("normal")
    assert E.shape == (5, 6) and np.linalg.matrix_rank(E) == 4
    z0 = -0.119 + 0.09
    np.testing.assert_allclose(np.array([z0, 0, 1, 0, 0]) @ E, 0, atol=1e-15)
    assert np.linalg.matrix_rank(effectiveness("paper")) == 5


# "normal": a derivation of its own (slow)
@pytest.mark.parametrize("actuators", ["paper", pytest.param("normal", marks=pytest.mark.slow)])
def test_derived_allocation_is_the_pseudoinverse(actuators: str) -> None:
    """controllers.allocation_matrix (derive.allocation's minimum-norm T) = pinv(E)."""
    c = DerivedCarriage(load_params(overrides=[f'control.actuators="{actuators}"']))
    T = allocation_matrix(c)
    np.testing.assert_allclose(T, np.linalg.pinv(effectiveness(actuators)), atol=1e-13)


def test_paper_geometry_normal_allocation_symbolic() -> None:
    """derive.allocation's exact E and T for the normal actuators of the paper's geometry."""
    from maglevgen.derive import allocation

    E = allocation.paper_normal_effectiveness()
    np.testing.assert_allclose(np.array(E, dtype=float), effectiveness("normal"), atol=1e-15)
    T = allocation.minimum_norm_allocation(E)
    assert E.pinv().applyfunc(sp.simplify) == T  # SymPy's own (exact) Moore-Penrose inverse
    np.testing.assert_allclose(np.array(T, dtype=float), np.linalg.pinv(effectiveness("normal")),
                               atol=1e-14)


def test_generated_c_allocation_with_normal_actuators(normal_carriage, normal_lib) -> None:
    """maglev_allocation_matrix and maglev_allocate of the generated C = numpy's pinv; the
    forces reproduce every reachable u_gen and are scipy's least-squares minimum-norm ones for
    any other."""
    p = normal_carriage.p
    (T,) = normal_lib.function("maglev_allocation_matrix")(p)
    E = effectiveness("normal")
    np.testing.assert_allclose(T, np.linalg.pinv(E), atol=1e-12)
    allocate = normal_lib.function("maglev_allocate")
    rng = np.random.default_rng(17)
    for _ in range(5):
        u_reachable = E @ rng.normal(size=6)
        (F,) = allocate(u_reachable, p)
        F = np.ravel(F)
        # each array's force along its own normal, summed as forces and moments about O here
        total = sum(wrench(r, f * n) for r, n, f in zip(POSITIONS, NORMALS, F, strict=True))
        np.testing.assert_allclose(total, u_reachable, atol=1e-11)
        u_any = rng.normal(size=5)
        (F_any,) = allocate(u_any, p)
        np.testing.assert_allclose(np.ravel(F_any), scipy.linalg.lstsq(E, u_any)[0],
                                   atol=1e-11)


def test_c_allocation_paper_actuators_is_the_pseudoinverse(op) -> None:
    np.testing.assert_allclose(op.allocation, np.linalg.pinv(effectiveness("paper")),
                               atol=1e-12)


def test_model_applies_each_normal_force_along_its_normal(normal_carriage) -> None:
    """In the symbolic model's wrench at the design pose, a unit F_n<i> adds a body force
    along n_i (cross product zero, unit along it) and its moment a_i x n_i about O."""
    model = normal_carriage.model
    values = dict(zip(model.p, normal_carriage.p, strict=True))
    # the arrays' forces zero: their points of action (arm_sym) and spreads do not matter
    zero = {s: 0 for s in (*model.x, *model.u, *model.lift_sym, *model.drag_sym,
                           *model.spread_sym, *model.arm_sym)}
    base = np.array(model.wrench.xreplace({**values, **zero}).evalf(), dtype=float).ravel()
    for i, (r, n) in enumerate(zip(POSITIONS, NORMALS, strict=True)):
        unit = {**values, **zero, model.u[1 + i]: 1}
        w = np.array(model.wrench.xreplace(unit).evalf(), dtype=float).ravel() - base
        force, moment = w[:3], w[3:]  # less the base's gravity (91 N): rounding of 1e-14
        np.testing.assert_allclose(np.cross(force, n), 0, atol=1e-13)
        assert force @ n == pytest.approx(1.0, abs=1e-13)
        np.testing.assert_allclose(moment, np.cross(r, n), atol=1e-13)


def test_simulated_array_forces_lie_along_the_normals(normal_carriage, normal_lib) -> None:
    """In a closed-loop run of the C with normal actuators, each array's control force is one
    number per array (F_n) and the generalized forces it makes are E F with E built here."""
    from maglevgen.analyses.simulate import Weights, metrics, operating_point, simulate

    prm = normal_carriage.params
    op = operating_point(normal_lib, normal_carriage.p, prm.operation.speed, prm.track.min_gap,
                         Weights.of(prm))
    traj = simulate(normal_lib, normal_carriage.p, op, "coupled", 0.2, 1e-3, prm.track.min_gap)
    traj.input_names = normal_carriage.model.input_names
    F = traj.u[:, 1:]
    assert F.shape[1] == 6
    np.testing.assert_allclose(traj.generalized_forces, F @ effectiveness("normal").T,
                               atol=1e-9)
    peaks = metrics(traj)["peak_array_force"]
    assert list(peaks) == [str(i) for i in range(1, 7)]
    np.testing.assert_allclose(list(peaks.values()), np.abs(F).max(axis=0), rtol=0, atol=0)


# ------------------------------------------------------------------------------ inertia


def test_box_inertia_against_a_triple_integral() -> None:
    """The model's box inertia = integral of rho (y^2 + z^2) dV etc. over a uniform box about
    its centre (SymPy integrate), in symbols; the products of inertia vanish."""
    from maglevgen.derive.model import inertia_cg_matrix

    m, ln, w, h = sp.symbols("m l w h", positive=True)
    x, y, z = sp.symbols("x y z", real=True)
    rho = m / (ln * w * h)

    def integral(f: sp.Expr) -> sp.Expr:
        return sp.integrate(rho * f, (x, -ln / 2, ln / 2), (y, -w / 2, w / 2), (z, -h / 2, h / 2))

    r = (x, y, z)
    reference = sp.Matrix(3, 3, lambda i, j: integral(
        (x**2 + y**2 + z**2 if i == j else 0) - r[i] * r[j]))
    names = ("vehicle.mass", "vehicle.length", "vehicle.width", "vehicle.height")
    sym = dict(zip(names, (m, ln, w, h), strict=True))
    inertia = inertia_cg_matrix(sym.__getitem__, names)
    assert (inertia - reference).applyfunc(sp.simplify) == sp.zeros(3, 3)


def _inertia_at(overrides: list[str]) -> np.ndarray:
    """The model's inertia about the CG at the parameter values (its symbols substituted)."""
    from maglevgen.derive.model import inertia_cg_matrix

    c = DerivedCarriage(load_params(overrides=overrides))
    model = c.model
    values = dict(zip(model.p, c.p, strict=True))
    inertia = inertia_cg_matrix(model.param, model.structure.param_names)
    return np.array(inertia.xreplace(values).evalf(), dtype=float)


def test_mass_doubles_the_box_inertia_and_leaves_the_explicit_one() -> None:
    explicit, explicit_2m = _inertia_at([]), _inertia_at(["vehicle.mass=18.6"])
    np.testing.assert_array_equal(explicit_2m, explicit)
    np.testing.assert_allclose(explicit, [[0.0794, 0, -0.004], [0, 0.358, 0], [-0.004, 0, 0.376]],
                               rtol=0, atol=0)
    box, box_2m = _inertia_at([BOX]), _inertia_at([BOX, "vehicle.mass=18.6"])
    np.testing.assert_allclose(box_2m, 2 * box, rtol=1e-15)
    # the default file's box: 9.3 kg, 0.65 x 0.25 x 0.20 m, its explicit diagonal to 3 figures
    ln, w, h = 0.65, 0.25, 0.20
    np.testing.assert_allclose(np.diag(box), 9.3 / 12 * np.array(
        [w**2 + h**2, ln**2 + h**2, ln**2 + w**2]), rtol=1e-15)
    np.testing.assert_allclose(np.diag(box), np.diag(explicit), rtol=2e-3)


def test_box_keeps_the_parameter_vector_free_of_the_tensor() -> None:
    """With "box" the tensor's entries leave the parameter vector (the box's dimensions enter
    it), so a sampled or overridden mass moves the inertia in the compiled model too."""
    names = [e.name for e in DerivedCarriage(load_params(overrides=[BOX])).entries]
    assert "vehicle.width" in names and "vehicle.height" in names
    assert not any(n.startswith("vehicle.inertia_cg") for n in names)
    default = [e.name for e in DerivedCarriage(load_params()).entries]
    assert "vehicle.width" not in default and "vehicle.inertia_cg.xz" in default


def test_api_gains_use_the_selected_actuators(normal_lib) -> None:
    """maglevgen.Carriage(...).gains() allocates with the file's actuator model."""
    import maglevgen

    api = maglevgen.Carriage(overrides=[NORMAL])
    assert api.input_names[1:] == tuple(f"F_n{i}" for i in range(1, 7))
    g = api.gains(controller="coupled")
    np.testing.assert_allclose(g.allocation, np.linalg.pinv(effectiveness("normal")), atol=1e-12)
    paper = maglevgen.Carriage().gains(controller="coupled")
    np.testing.assert_allclose(paper.allocation, np.linalg.pinv(effectiveness("paper")),
                               atol=1e-12)


# ------------------------------------------------------------------------------ firmware C

#: the host flags under which the firmware's C must compile without a warning (tests/
#: test_firmware.py's WARN)
WARN = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wdouble-promotion",
        "-Wfloat-conversion", "-Wconversion"]


@pytest.fixture(scope="module")
def normal_firmware(normal_carriage, normal_lib, tmp_path_factory):
    """The single-precision baked C (`generate --precision single --params baked --int
    int32`) with normal actuators, compiled for the host with WARN; its library."""
    import subprocess

    from maglevgen.codegen.generate import GenerateOptions, render, write_output
    from runtime.ffi import GeneratedLibrary

    out = tmp_path_factory.mktemp("normal_firmware")
    write_output(render(normal_carriage, GenerateOptions("single", "baked", "int32"),
                        Plant(normal_carriage, normal_lib).speed_range), out)
    cc = subprocess.run(["cc", *WARN, "-O1", "-fPIC", "-shared", "maglev_functions.c", "-o",
                         "maglev.so", "-lm"], cwd=out, capture_output=True, text=True)
    assert cc.returncode == 0 and not cc.stderr, cc.stderr[-3000:]
    return GeneratedLibrary(out / "maglev.so", "single", "int32")


@pytest.mark.slow  # a firmware folder for the normal-actuator carriage
@pytest.mark.needs_cc
def test_firmware_allocation_with_normal_actuators(normal_firmware) -> None:
    """The firmware's maglev_allocate (single, baked) gives one force per array, numpy's
    pinv(E) u_gen to single precision; those forces, each along its array's normal, sum to
    the commanded generalized forces (every reachable u_gen) or to its projection on E's
    range (any other: the roll about the normals' crossing line is lost)."""
    allocate = normal_firmware.function("maglev_allocate")
    E = effectiveness("normal")
    rng = np.random.default_rng(16)
    for reachable in (True, True, True, False, False):
        u = E @ rng.normal(scale=30.0, size=6) if reachable else rng.normal(scale=30.0, size=5)
        (F,) = allocate(u)
        F = np.ravel(F).astype(float)
        assert F.shape == (6,)
        np.testing.assert_allclose(F, np.linalg.pinv(E) @ u, rtol=0,
                                   atol=1e-5 * np.abs(u).max())
        total = sum(wrench(r, f * n) for r, n, f in zip(POSITIONS, NORMALS, F, strict=True))
        target = u if reachable else E @ np.linalg.lstsq(E, u, rcond=None)[0]
        np.testing.assert_allclose(total, target, rtol=0, atol=1e-5 * np.abs(u).max())


@pytest.mark.needs_cc
def test_firmware_dynamics_push_each_array_along_its_normal(normal_firmware, carriage,
                                                            normal_carriage, sim_lib,
                                                            op) -> None:
    """The firmware's maglev_dynamics (normal actuators, single, baked) at a moving, rotating
    state near the trim equals the paper-actuator model's (double, run-time parameters) given
    each array's force split here into its normal's body y and z parts: the C applies each
    F_n along its array's normal. A force applied along body z only would differ by
    |F| (1 - 1/sqrt 2) / m ~ 2 m/s^2."""
    np.testing.assert_array_equal(normal_carriage.p, carriage.p)
    rng = np.random.default_rng(6)
    x = np.asarray(op.x_trim, dtype=float).ravel().copy()
    x[1:6] += rng.normal(scale=1e-3, size=5)  # pose
    x[7:12] += rng.normal(scale=1e-2, size=5)  # velocity and rates
    dyn = normal_firmware.function("maglev_dynamics")
    paper = sim_lib.function("maglev_dynamics")
    for _ in range(3):
        F_n = rng.normal(scale=60.0, size=6)
        u_normal = np.concatenate([[op.f_prop], F_n])
        split = []  # F_y1, F_z1, F_y2, F_z2, F_z3, ... (the paper's order)
        for n, f in zip(NORMALS, F_n, strict=True):
            split += [f * n[1], f * n[2]] if n[1] != 0 else [f * n[2]]
        u_paper = np.concatenate([[op.f_prop], split])
        (got,) = dyn(x, u_normal)
        (ref,) = paper(x, u_paper, carriage.p)
        got, ref = np.ravel(got).astype(float), np.ravel(ref)
        scale = np.abs(ref[6:]).max()
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5 * scale)
