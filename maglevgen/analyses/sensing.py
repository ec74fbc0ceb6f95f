"""The embedded controller's sensing across the envelope: what the sensors of ``[sensors]``
observe, the Kalman filter at the tick, and the whole loop with the estimator, as checks of
`maglevgen build`'s verdict (maglevgen.analyses.verdicts) and `maglevgen envelope`.

At each envelope speed (the envelope's operating points: the generated C's trim and
Jacobians):

- observability (maglevgen.control.estimation.observability): the rank and smallest singular
  value of the noise-scaled discrete observability matrix of the plant's states; a state the
  controller needs in its null space fails the check, named with why (`_why_blind`);
- the steady-state Kalman filter at the tick on the ZOH model with the delay and the actuator
  lag (`estimator_model` with [actuators] time_constant): each state's error (1 sigma after
  the update) against ESTIMATION_SHARE x control.spec.max_deviation (`estimation_failures`);
- the whole loop (`loop_as_built`): the plant with its lag and delay, the sensors, the filter,
  and the embedded controller's gains as the loop as built runs them (the `spec` design at the
  tick on control.plant.LoopPlant, the gains the output-feedback tick is to run) on the
  estimate: its smallest damping ratio, slowest decay and slowest levitation decay against
  ``[control.spec]`` (envelope.spec_failures).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from maglevgen.control.built_loop import LoopSetting
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.estimation import (
    ESTIMATION_SHARE,
    EstimatorPoint,
    NoKalmanFilterError,
    SensorLayout,
    continuous_equivalent,
    estimation_failures,
    estimator_model,
    kalman,
    loop_as_built,
    loop_as_built_speed_states,
    observability,
    why_blind,
)
from maglevgen.control.operating import OperatingPoint, stability
from maglevgen.control.plant import LoopDesign, LoopPlant
from maglevgen.controllers import controller as registered_controller
from maglevgen.derive import conventions as cv

__all__ = ["SensingCheck", "sensing_check"]


@dataclass(frozen=True)
class SensingCheck:
    """The sensing checks of the module docstring at the envelope's speeds."""

    speeds: np.ndarray
    sensors: str  # the set in words (SensorLayout.describe)
    controller: str
    gains: str  # which gains the whole loop closes, in words
    loop: str  # the loop in words (tick, delay, lag)
    loop_short: str  # the same, in a few words
    n_states: int  # the plant's states the observability matrix holds
    rank: np.ndarray  # per speed
    smallest: np.ndarray  # smallest singular value (noise-scaled), per speed
    largest: np.ndarray
    blind: tuple[str, ...]  # "state: why" for each needed state unobservable somewhere
    blind_speeds: tuple[float, ...]  # where
    error_std: np.ndarray  # (speeds, states): the filter's 1-sigma error after the update
    states: tuple[str, ...]
    estimation: tuple[str, ...]  # axes estimated worse than the share allows, one sentence each
    gain_norm: np.ndarray  # the update gain M's largest singular value, per speed
    max_real: np.ndarray  # the whole loop, per speed
    min_damping: np.ndarray
    levitation_real: np.ndarray
    speed_real: np.ndarray
    filter_real: np.ndarray  # the filter's own modes' largest real part
    failures: tuple = ()  # envelope.SpecFailure of the whole loop
    verdict: str = ""  # the whole loop's spec verdict (envelope.spec_verdict_text)

    @property
    def observable(self) -> bool:
        return not self.blind

    @property
    def ok(self) -> bool:
        return self.observable and not self.estimation and not self.failures

    def _span(self) -> str:
        return f"[{self.speeds[0]:.4g}, {self.speeds[-1]:.4g}] m/s"

    def observability_subject(self) -> str:
        return (f"observability and the Kalman filter at the tick, across {self._span()} "
                f"({self.speeds.size} speeds; {self.sensors} of [sensors]; the ZOH model "
                "with the delay and the actuator lag)")

    def observability_text(self) -> str:
        """Rank and smallest singular value per speed range, then the filter's verdict."""
        if self.blind:
            where = ", ".join(f"{v:.4g}" for v in self.blind_speeds)
            return (f"FAILS: cannot observe what the controller needs (rank "
                    f"{int(np.min(self.rank))} of {self.n_states} at {where} m/s): "
                    + "; ".join(self.blind))
        i, j = int(np.argmin(self.smallest)), int(np.argmax(self.smallest))
        said = (f"rank {self.n_states} of {self.n_states} at every speed; smallest singular "
                f"value of the noise-scaled observability matrix {self.smallest[i]:.4g} (at "
                f"{self.speeds[i]:.4g} m/s) to {self.smallest[j]:.4g} (at "
                f"{self.speeds[j]:.4g} m/s)")
        if self.estimation:
            return f"FAILS: {said}, but " + "; ".join(self.estimation)
        worst = {s: float(np.max(self.error_std[:, k])) for k, s in enumerate(self.states)}
        axes = ", ".join(f"{s} {worst[s]:.3g}" for s in cv.Q_STATES)
        return (f"{said}; the filter's error (1 sigma) within {ESTIMATION_SHARE:g} x "
                f"control.spec.max_deviation on every axis (worst: {axes}; m, rad)")

    def loop_subject(self) -> str:
        return (f"the whole loop with the estimator, linear, across {self._span()} (the "
                f"plant's linearisation, the sensors, the Kalman filter, {self.gains} on its "
                f"estimate; {self.loop})")

    def loop_text(self) -> str:
        if self.blind:
            return "FAILS: no Kalman filter (the sensors cannot observe the loop's states)"
        known = self.filter_real[np.isfinite(self.filter_real)]
        if known.size < self.filter_real.size:  # no filter (or no gains) somewhere
            return self.verdict
        return (f"{self.verdict}; the filter's own modes decay at least at "
                f"{-np.max(known):.4g} 1/s")

    def verdict_subject(self) -> str:
        """The verdict block's line (short: page 1 of the report carries the block; the long
        forms are `observability_text` and `loop_text`)."""
        return (f"sensing, linear, across {self._span()} ({self.sensors}; Kalman filter and "
                f"`{self.controller}` at the tick, {self.loop_short})")

    def verdict_text(self) -> str:
        if self.blind:
            return "FAILS: cannot observe " + "; ".join(self.blind)
        if self.estimation or self.failures:
            return "FAILS: " + "; ".join(
                [*self.estimation, *(f"whole loop {f.text()}" for f in self.failures)])
        return (f"observable (rank {self.n_states} of {self.n_states}, smallest singular value "
                f"{np.min(self.smallest):.3g}), errors within {ESTIMATION_SHARE:g} x "
                "max_deviation; whole loop with the estimator: damping ratio >= "
                f"{np.min(self.min_damping):.3g}, levitation decay >= "
                f"{np.min(-self.levitation_real):.4g} 1/s")

    def reason(self) -> str | None:
        """What fails, in one clause (`verdicts.embedded_verification`), None: all pass."""
        out = []
        if self.blind:
            out.append("its sensors cannot observe what it needs: " + "; ".join(self.blind))
        elif self.estimation:
            out.append("its Kalman filter fails: "
                       + "; ".join(self.estimation))
        if self.failures:
            out.append("the whole loop with the estimator "
                       + "; ".join(f.text() for f in self.failures))
        return "; ".join(out) or None

    def to_json(self) -> dict:
        return {"speeds": self.speeds.tolist(), "sensors": self.sensors,
                "observability_rank": self.rank.tolist(), "n_states": self.n_states,
                "observability_smallest_singular_value": self.smallest.tolist(),
                "unobservable": list(self.blind),
                "estimation_error_std": {s: self.error_std[:, k].tolist()
                                         for k, s in enumerate(self.states)},
                "estimation_failures": list(self.estimation),
                "kalman_gain_norm": self.gain_norm.tolist(),
                "whole_loop": {"gains": self.gains, "loop": self.loop,
                               "max_real": self.max_real.tolist(),
                               "min_damping": self.min_damping.tolist(),
                               "levitation_max_real": self.levitation_real.tolist(),
                               "filter_max_real": self.filter_real.tolist(),
                               "verdict": self.verdict}}


def sensing_check(plant: Plant, points: Sequence[OperatingPoint], setting: LoopSetting,
                  controller: str, loops: Sequence[tuple[LoopPlant, LoopDesign | None]],
                  judge: Callable[[np.ndarray], tuple[tuple, str]]) -> SensingCheck:
    """`SensingCheck` of ``controller`` (the embedded one) at ``points`` with the loop of
    ``setting`` (loop.LoopSetting): ``loops`` its plant and gains at each point (None:
    no design there), ``judge`` the envelope's verdict on the per-speed rows (largest real
    part, smallest damping ratio, levitation and speed loops' largest real parts):
    (failures, verdict text)."""
    carriage, lib = plant.carriage, plant.lib
    params = carriage.params
    layout = SensorLayout.of(params)
    speeds = np.array([op.speed for op in points])
    tau = setting.actuator_lag
    nan = float("nan")
    rank, small, large, gain, err = [], [], [], [], []
    estimated: list[EstimatorPoint] = []
    rows, filt = [], []
    blind: dict[str, str] = {}
    blind_at: list[float] = []
    no_filter: list[str] = []  # NoKalmanFilterError's sentence at each speed without one
    states: tuple[str, ...] = ()
    for op, (built, gains) in zip(points, loops, strict=True):
        model = estimator_model(lib, carriage.p, op, params, layout, tau)
        states = model.states
        obs = observability(model)
        rank.append(obs.rank)
        small.append(obs.smallest)
        large.append(float(obs.singular_values[0]))
        if obs.unobservable:
            for s in obs.unobservable:
                blind.setdefault(s, f"{s}: {why_blind(s, layout, params)}")
            blind_at.append(op.speed)
            gain.append(nan)
            err.append(np.full(model.n_x, nan))
            rows.append((np.inf, nan, np.inf, np.inf))
            filt.append(np.inf)
            continue
        try:
            design = kalman(model)
        except NoKalmanFilterError as exc:
            no_filter.append(str(exc))
            gain.append(nan)
            err.append(np.full(model.n_x, nan))
            rows.append((np.inf, nan, np.inf, np.inf))
            filt.append(np.inf)
            continue
        estimated.append(EstimatorPoint(model, obs, design))
        gain.append(float(np.linalg.norm(design.M[:model.n_x], 2)))
        err.append(np.sqrt(np.clip(np.diag(design.P_updated)[:model.n_x], 0.0, None)))
        if gains is None:
            rows.append((np.inf, nan, np.inf, np.inf))
            filt.append(nan)
            continue
        loop = loop_as_built(model, design, built, gains)
        rows.append(_loop_numbers(loop, model, built, setting.tick.period))
        fs = continuous_equivalent(model.Phi @ (np.eye(model.Phi.shape[0])
                                                - design.M @ model.C), setting.tick.period)
        filt.append(float(np.max(fs[np.isfinite(fs.real)].real)))
    err_a = np.array(err)
    sd = np.array(rows)
    estimation: tuple[str, ...] = ()
    if blind:
        failures, verdict = (), "not computed: no Kalman filter"
    elif no_filter:
        estimation = tuple(no_filter)
        failures, verdict = (), "FAILS: not computed where there is no Kalman filter"
    else:
        estimation = tuple(estimation_failures(estimated, params))
        failures, verdict = judge(sd)
    design_said = ("the `spec` design at the tick on the loop as built"
                   if registered_controller(controller).tick_design
                   else "its continuous gains")
    return SensingCheck(
        speeds, layout.describe(), controller,
        f"the `{controller}` gains ({design_said}, which the output-feedback tick is to run; "
        "the generated full-state tick runs the continuous gains)",
        setting.tick_text(),
        f"{setting.tick.rate:g} Hz, {setting.tick.delay} tick delay, {1e3 * tau:.3g} ms lag",
        len(states), np.array(rank), np.array(small), np.array(large),
        tuple(blind.values()), tuple(dict.fromkeys(blind_at)), err_a, states, estimation,
        np.array(gain), sd[:, 0], sd[:, 1], sd[:, 2], sd[:, 3], np.array(filt), failures,
        verdict)


def _loop_numbers(loop: np.ndarray, model, plant, period: float
                  ) -> tuple[float, float, float, float]:
    """(largest real part, smallest damping ratio, the levitation modes' largest real part,
    the speed loop's) of `loop_as_built`: the modes split by participation factors (as
    control.plant.LoopPlant.modes) on `loop_as_built_speed_states`."""
    z, left, right = scipy.linalg.eig(loop, left=True, right=True)
    scale = np.einsum("ij,ij->j", left.conj(), right)
    part = np.abs(left.conj() * right / np.where(np.abs(scale) > 0, scale, 1.0))
    L = plant.loop_layout
    n_w = L["prediction"].stop - L["prediction"].start
    mask = loop_as_built_speed_states(model, n_w,
                                      L["speed_integral"].stop - L["speed_integral"].start)
    speed = part[mask].sum(axis=0) > 0.5 * part.sum(axis=0)
    small = np.abs(z) < 1e-300
    s = np.log(np.where(small, 1.0, z.astype(complex))) / period
    s = np.where(small, -np.inf + 0j, s)
    finite = np.isfinite(s)
    max_real, min_damping = stability(s[finite])
    lev = float(np.max(s[finite & ~speed].real))
    spd = float(np.max(s[finite & speed].real)) if np.any(finite & speed) else -np.inf
    return max_real, min_damping, lev, spd
