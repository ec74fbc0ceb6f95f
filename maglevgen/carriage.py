"""A carriage: validated parameters joined to its symbolic model, trim and linearisation.

This is the numeric layer the CLI, code generator and report share; it calls into derive/
(symbolic, pure) and never writes files.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.derive import conventions as cv
from maglevgen.derive.structure import Structure, control_components
from maglevgen.errors import NoTrimError
from maglevgen.infrastructure.cache import install_store
from maglevgen.params import LoadedParams, ModelChoices, Parameters, flatten

if TYPE_CHECKING:  # the symbolic layers are imported when first used: running the compiled
    # model (maglevgen simulate, the build's simulations) needs only the parameters
    from maglevgen.derive.model import CarriageModel
    from maglevgen.derive.numeric import ModelFunctions
    from maglevgen.derive.trim import Trim

__all__ = ["DerivedCarriage", "stiffness_rows", "structure_of"]


def structure_of(params: Parameters) -> Structure:
    """The structure of a validated parameter set (what the derivation depends on)."""
    arrays = tuple((name, control_components(arr.normal, params.control.actuators))
                   for name, arr in params.arrays.items())
    return Structure(tuple(e.name for e in flatten(params)), arrays, params.model.array_force,
                     params.model.circuit_dynamics)


@dataclass(frozen=True)
class StiffnessRow:
    """One axis of the stiffness table: derived (at trim) beside the paper's printed form."""

    axis: str
    unit: str
    derived_magnetic: float
    derived_total: float
    paper_formula: str
    paper_value: float

    @property
    def relative_difference(self) -> float:
        return (self.paper_value - self.derived_magnetic) / self.derived_magnetic


_STIFFNESS_UNITS = {"lateral": "N/m", "vertical": "N/m", "roll": "N*m/rad", "pitch": "N*m/rad",
                    "yaw": "N*m/rad"}


class DerivedCarriage:
    """Parameters, model and derived numbers of one carriage."""

    def __init__(self, loaded: LoadedParams) -> None:
        self.loaded = loaded
        self.params = loaded.params
        self.entries = flatten(self.params)
        self.p = np.array([e.value for e in self.entries])
        self._trims: dict[float, Trim] = {}
        install_store()  # the derivation's memoised steps, shared across processes

    @cached_property
    def structure(self) -> Structure:
        return structure_of(self.params)

    @cached_property
    def functions(self) -> ModelFunctions:
        """The lambdified model: an independent reference for the compiled library (the
        report's verification table, `simulate --check`, the tests), never the source of a
        printed number (maglevgen.analyses.queries reads those from the C). Memoised across
        processes
        (derive.memo, maglevgen.infrastructure.cache) under a content hash of derive/'s sources."""
        from maglevgen.derive.numeric import model_functions

        return model_functions(self.structure)

    @property
    def model(self) -> CarriageModel:
        """The symbolic model (what the report displays): SymPy only, nothing lambdified."""
        from maglevgen.derive.numeric import symbolic_model

        return symbolic_model(self.structure)

    def trim(self, speed: float | None = None) -> Trim:
        """The equilibrium at ``speed`` (default: operation.speed), solved once per speed."""
        from maglevgen.derive import trim

        v = float(self.params.operation.speed if speed is None else speed)
        if v not in self._trims:
            try:
                self._trims[v] = trim.solve_trim(self.functions, self.p, v,
                                                 self.params.track.min_gap)
            except trim.NoTrimError as exc:  # derive/'s, reported as bad input (exit 2)
                raise NoTrimError(str(exc)) from None
        return self._trims[v]

    def lift_off_speed(self) -> float:
        """The lowest speed with an equilibrium (a bisection over trims: solved once)."""
        return self._lift_off

    @cached_property
    def _lift_off(self) -> float:
        from maglevgen.derive.trim import lift_off_speed

        return lift_off_speed(self.functions, self.p, self.params.track.min_gap)

    def linearize(self, trim: Trim) -> tuple[np.ndarray, np.ndarray]:
        from maglevgen.derive.numeric import linearize

        return linearize(self.functions, trim, self.p)

    def magnetic_stiffness(self, trim: Trim) -> np.ndarray:
        from maglevgen.derive.numeric import magnetic_stiffness

        return magnetic_stiffness(self.functions, trim, self.p)

    def total_stiffness(self, trim: Trim) -> np.ndarray:
        from maglevgen.derive.numeric import other_stiffness

        return self.magnetic_stiffness(trim) + other_stiffness(self.functions, trim, self.p)

    def stiffness_parts(self, trim: Trim) -> dict[str, np.ndarray]:
        """K_st0 + K_other at trim split by where the pose enters the wrench (gap slope,
        rotating arms, tilt across the face, gravity, propulsion: derive.linearize), from the
        lambdified split: the tests' reference for the library's maglev_stiffness_parts (what
        the report prints)."""
        from maglevgen.derive.numeric import stiffness_split

        return stiffness_split(self.structure, trim, self.p)

    def with_array_force(self, law: str) -> DerivedCarriage:
        """This carriage with model.array_force = ``law`` (itself when it already has it)."""
        if law == self.params.model.array_force:
            return self
        return self._with_model("array_force", law)

    def with_circuit_dynamics(self, dynamics: str) -> DerivedCarriage:
        """This carriage with model.circuit_dynamics = ``dynamics`` (itself when it has it)."""
        if dynamics == self.params.model.circuit_dynamics:
            return self
        return self._with_model("circuit_dynamics", dynamics)

    def _with_model(self, key: str, value: str) -> DerivedCarriage:
        """This carriage with model.<key> = ``value``, the other model choices kept."""
        choices = ModelChoices(**{**self.params.model.model_dump(), key: value})
        params = self.params.model_copy(update={"model": choices})
        return DerivedCarriage(LoadedParams(params, self.loaded.source, self.loaded.sha256,
                                     (*self.loaded.overrides, f'model.{key}="{value}"')))

    def generalized_mass(self) -> np.ndarray:
        from maglevgen.derive.numeric import generalized_mass

        return generalized_mass(self.model, self.p)

    def _array_roles(self) -> tuple[list[int], list[int]]:
        """Indices of upper arrays (normal along z only) and of the others (lower, lateral)."""
        upper: list[int] = []
        lower: list[int] = []
        for i, arr in enumerate(self.params.arrays.values()):
            (upper if abs(arr.normal[2]) > 1 - 1e-9 else lower).append(i)
        return upper, lower

    def paper_stiffness_inputs(self, trim: Trim) -> dict[str, float]:
        """The quantities the paper's eqs 13-19 use, read from the geometry and the trim."""
        upper, lower = self._array_roles()
        arrays = list(self.params.arrays.values())
        f_lat = float(np.mean([trim.lift[i] * abs(arrays[i].normal[1]) for i in lower]))
        return {
            "F_lat": f_lat,  # F_bncd_y: lateral component of one lower array's lift
            "F_upper": float(np.mean([trim.lift[i] for i in upper])),
            "m": self.params.vehicle.mass,
            "g": self.params.vehicle.gravity,
            "k": self.params.wavenumber,
            "Lz": float(np.mean([abs(arrays[i].position[2]) for i in lower])),
            "Lx": float(np.mean([abs(arrays[i].position[0]) for i in upper])),
            "Lxla": float(np.mean([abs(arrays[i].position[0]) for i in lower])),
        }

    def stiffness_table(self, trim: Trim) -> list[StiffnessRow]:
        """Per-axis stiffness: derived K_st0 diagonal (and with gravity) beside eqs 13-19."""
        return stiffness_rows(self.paper_stiffness_inputs(trim), self.magnetic_stiffness(trim),
                              self.total_stiffness(trim))


def stiffness_rows(kin: dict[str, float], K_mag: np.ndarray,
                   K_tot: np.ndarray) -> list[StiffnessRow]:
    """Per-axis rows of K_st0 (magnetic) and of the total stiffness beside the paper's printed
    eqs 13-19 evaluated at ``kin`` (`DerivedCarriage.paper_stiffness_inputs`)."""
    import sympy as sp

    from maglevgen.derive.paper import paper_stiffness

    syms = {name: sp.Symbol(name) for name in kin}
    printed = paper_stiffness(**syms)
    rows = []
    for i, axis in enumerate(cv.AXES):
        expr = printed[axis]
        rows.append(StiffnessRow(axis, _STIFFNESS_UNITS[axis], float(K_mag[i, i]),
                                 float(K_tot[i, i]), sp.sstr(expr),
                                 float(expr.xreplace({syms[n]: v for n, v in kin.items()}))))
    return rows
