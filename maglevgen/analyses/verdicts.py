"""The embedded controller's verdict as `maglevgen build` decides its exit code, in one place.

Every check that decides the exit code (3: verification failed) is one `VerdictLine` here:
the linear specification across the envelope on the loop as built, the gains on the other
models, the judged hold and launch runs (where the file has [sensors], flown by the
firmware's sense tick on noisy readings; each on the worst sign combination of the default
disturbance, `maglevgen.analyses.worst_case`) and the region of attraction (a region
confirmed by firmware-loop runs at every speed of the build's study).
`EmbeddedVerdict.lines` is the block that SUMMARY.md, `build`'s stdout and the report's first
page print (the report typesets the same lines: `maglevgen.report.sections.summary`), and
`EmbeddedVerdict.reason` the one reason `build` exits 3 with: both from the same checks, so
the first page cannot say "meets" where the build fails.

The other registered controllers (the paper's designs, the coupled LQR) are `findings`: what
the toolchain finds about them, listed apart; they do not decide the exit code.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from maglevgen.errors import InputError
from maglevgen.infrastructure.hashing import ContentHash

if TYPE_CHECKING:
    from maglevgen.analyses.output_feedback import NoisyHold
    from maglevgen.analyses.roa import Region
    from maglevgen.analyses.run_spec import RunVerdict
    from maglevgen.control.carriage_plant import Plant

__all__ = ["EmbeddedVerdict", "JudgedRun", "build_holds", "cached_verdict", "embedded_runs",
           "embedded_verdict", "generate_example", "store_verdict", "verify_embedded"]

#: the judged runs' length [s] and step [s] (`maglevgen build`'s defaults)
RUN_T_END, RUN_DT = 10.0, 1e-3


@dataclass(frozen=True)
class JudgedRun:
    """One run of the embedded controller that `build` judges against ``[control.spec]``."""

    label: str  # "hold run at 40 m/s", "launch run (6.543 to 40 m/s)"
    verdict: RunVerdict
    command: str  # the `maglevgen simulate` that repeats it
    loop: str = "firmware"  # the loop it flew (simulate's --loop): "firmware" or "sensed"

    def loop_text(self) -> str:
        """The loop in words, for the verdict's line."""
        return ("the firmware's sense tick on noisy readings" if self.loop == "sensed"
                else "firmware loop, ideal sensing")


@dataclass(frozen=True)
class VerdictLine:
    """One check that decides `build`'s exit code (or, in `EmbeddedVerdict.findings`, one
    finding about another controller): what was checked, where and on what, and the verdict.
    Code (names, commands) in backticks: Markdown as is, the report typesets it."""

    subject: str
    text: str
    ok: bool

    def line(self) -> str:
        return f"{self.subject}: {self.text}"

    def to_json(self) -> dict:
        return {"subject": self.subject, "verdict": self.text, "ok": self.ok}

    @classmethod
    def from_json(cls, d: dict) -> VerdictLine:
        return cls(str(d["subject"]), str(d["verdict"]), bool(d["ok"]))


@dataclass(frozen=True)
class EmbeddedVerdict:
    """The embedded controller's verdict as `build` decides its exit code (the module
    docstring), for SUMMARY.md, stdout, the report's first page and what `firmware` and `fmu`
    write: the verdict, the spec, the model and the range."""

    controller: str
    reason: str | None  # why the verification failed (build exits 3), None: verified
    model: str  # what the spec was checked on (Envelope.checked_on)
    v_min: float
    v_max: float
    checks: tuple[VerdictLine, ...] = ()  # every check deciding the exit code
    findings: tuple[VerdictLine, ...] = ()  # the other controllers: not deciding it
    title: str = ""  # the controller's title (CONTROLLER_TITLES)
    complete: bool = True  # False: the runs and the region were not run (report alone)

    @property
    def verified(self) -> bool:
        return self.reason is None

    def head(self) -> str:
        """The block's first line: what, against what, where, and the verdict."""
        what = (f"The embedded controller `{self.controller}` ({self.title}) against "
                f"[control.spec] over [{self.v_min:.4g}, {self.v_max:.4g}] m/s")
        if not self.complete:
            return (f"{what}: NOT VERIFIED HERE: the linear checks only; the judged runs and "
                    "the region of attraction that also decide `maglevgen build`'s exit code "
                    "were not run for this report (`maglevgen build` runs them)")
        n = len(self.checks)
        if self.reason is None:
            checks = "the check below passes" if n == 1 else f"all {n} checks below pass"
            return f"{what}: VERIFIED, {checks} (`maglevgen build` exits 0)"
        failed = sum(not c.ok for c in self.checks)
        checks = (f"{failed} of {n} checks below {'fails' if failed == 1 else 'fail'}" if n > 1
                  else "the check below fails")
        return f"{what}: FAILS, {checks} (`maglevgen build` exits 3 unless --allow-unstable)"

    def findings_head(self) -> str:
        return ("Findings about the other controllers (the paper's designs and the coupled "
                "LQR; they do not decide the exit code):")

    def lines(self) -> list[str]:
        """The verdict block (Markdown; code in backticks): the head, every check, then the
        findings. SUMMARY.md, stdout and the report's first page print these lines."""
        out = [self.head(), "", *(f"- {c.line()}" for c in self.checks)]
        if self.findings:
            out += ["", self.findings_head(), "", *(f"- {c.line()}" for c in self.findings)]
        return out

    def text(self) -> str:
        """One line: verified (what, where, on what) or the failure."""
        if self.reason is not None:
            return f"NOT VERIFIED: {self.reason}"
        return (f"verified: the embedded controller {self.controller!r} meets [control.spec] "
                f"across [{self.v_min:.4g}, {self.v_max:.4g}] m/s, checked {self.model}, in "
                "its hold and launch runs (where the file has [sensors] flown by the "
                "firmware's sense tick on noisy readings), each judged on the worst "
                "sign combination of the default disturbance, with a region of attraction "
                "confirmed at every speed studied, and, where the file has [sensors], with "
                "its sensors observing what it needs, its Kalman filter, the whole loop with "
                "the estimator and its noisy holds (the check `maglevgen build` exits 3 on)")

    def to_json(self) -> dict:
        return {"verified": self.verified, "verdict": self.text(), "controller": self.controller,
                "spec": "[control.spec]", "model": self.model,
                "range_m_per_s": [self.v_min, self.v_max],
                "checks": [c.to_json() for c in self.checks]}

    def stored(self) -> dict:
        """What the cache keeps (`store_verdict`)."""
        return {"controller": self.controller, "reason": self.reason, "model": self.model,
                "v_min": self.v_min, "v_max": self.v_max, "title": self.title,
                "checks": [c.to_json() for c in self.checks],
                "findings": [c.to_json() for c in self.findings]}

    @classmethod
    def from_stored(cls, d: dict) -> EmbeddedVerdict:
        return cls(str(d["controller"]), d["reason"], str(d["model"]), float(d["v_min"]),
                   float(d["v_max"]), tuple(VerdictLine.from_json(c) for c in d["checks"]),
                   tuple(VerdictLine.from_json(c) for c in d["findings"]), str(d["title"]))


def embedded_runs(plant: Plant, env, speed: float, t_end: float = RUN_T_END,
                  dt: float = RUN_DT) -> tuple[JudgedRun, ...]:
    """The embedded controller as the firmware flies it, judged against ``[control.spec]``
    (`maglevgen.analyses.run_spec`): held at envelope.v_min, at ``speed`` (the build's run
    speed, operation.speed) and at v_max for ``t_end``, and launched from v_min to v_max, the
    ends and the launch being where the linear verdict's worst cases lie (the gains' ends of
    the table, the accelerating trim's smallest gaps). Each from every sign combination of the
    default disturbance, judged on the worst (`maglevgen.analyses.worst_case`). Where the file
    has [sensors] every run flies the firmware's sense tick on noisy readings (seeded: the
    same noise from every start), as a carriage flies it (the launch with its acceleration as
    the reference's slope); without, the firmware loop on the exact state."""
    from maglevgen.analyses.sim_loop import flown_loop
    from maglevgen.analyses.simulate import DISTURBANCE, run_scenarios, spec_verdict
    from maglevgen.analyses.worst_case import sign_combinations, worst_verdict

    name = plant.params.envelope.embedded_controller
    combos = sign_combinations(DISTURBANCE)

    def judged(sim) -> RunVerdict:
        runs = [(d, spec_verdict(t)) for d, t in zip(combos, sim.trajectories, strict=True)]
        return worst_verdict([(d, v) for d, v in runs if v is not None])

    loop = flown_loop(plant)
    out = []
    for v in sorted({env.v_min, env.v_max, speed}):
        sim = run_scenarios(plant, (name,), t_end, dt, v, loop=loop, disturbances=combos)
        out.append(JudgedRun(f"hold run at {v:.4g} m/s", judged(sim),
                             f"maglevgen simulate --controller {name} --speed {v:.4g} "
                             f"--loop {loop.value} --disturbance STATE=VALUE ...", loop.value))
    launched = run_scenarios(plant, (name,), t_end, dt, scenario="launch", loop=loop,
                             disturbances=combos)
    out.append(JudgedRun(f"launch run ({launched.op.speed:.4g} to {launched.v_end:.4g} "
                         "m/s)", judged(launched),
                         f"maglevgen simulate --controller {name} --scenario launch "
                         f"--loop {loop.value} --disturbance STATE=VALUE ...", loop.value))
    return tuple(out)


def build_holds(plant: Plant, v_min: float, v_max: float, t_end: float = RUN_T_END
                ) -> tuple[NoisyHold, ...]:
    """The build's noisy holds as the firmware flies them (output_feedback.sensed_holds: its
    sense tick, compiled for the host, on the plant's noisy readings) over [v_min, v_max], their
    length BUILD_HOLD (20 s) scaled as the build's runs' ``t_end`` to RUN_T_END (a build with
    --t-end 1 holds for 2 s); none when the file has no [sensors] or they cannot observe what
    the controller needs or SciPy's DARE finds no filter (the sensing check fails the verdict
    then)."""
    if plant.params.sensors is None:
        return ()
    from maglevgen.analyses.output_feedback import BUILD_HOLD, sensed_holds
    from maglevgen.control.estimation import NoKalmanFilterError

    try:
        return sensed_holds(plant, v_min, v_max, BUILD_HOLD * t_end / RUN_T_END)
    except (InputError, NoKalmanFilterError):  # estimation.check_observable, kalman
        return ()


def _region_failures(region: Region | None) -> list[str]:
    """The speeds of ``region`` where no region of attraction was confirmed."""
    if region is None:
        return []
    return [f"{r.speed:.4g}" for r in region.regions if not (r.confirmed and r.level > 0)]


def embedded_verification(carriage, env, runs: tuple[JudgedRun, ...] = (),
                          region: Region | None = None,
                          holds: tuple[NoisyHold, ...] = ()) -> str | None:
    """None when the embedded controller is stable and meets ``[control.spec]`` across the
    envelope (the linear verdict, on every model checked), in each of ``runs``
    (`embedded_runs`) and has a region of attraction confirmed at every speed of ``region``
    (`maglevgen.analyses.roa`), else the one-line reason `build` exits 3 with: every failed
    spec, its value, its limit and where."""
    name = carriage.params.envelope.embedded_controller
    c = env.controllers[name]
    head = f"verification failed: the embedded controller envelope.embedded_controller = {name!r}"
    if not c.ok:
        return f"{head} is {c.verdict} (maglevgen envelope; --allow-unstable to accept)"
    failed, where = [], []
    if not c.meets_spec:
        failed.append(f"{c.spec_verdict}, {env.checked_on()}")
        where.append("maglevgen envelope")
    if not env.robust:
        failed.append("meets the specification on the carriage's model but its gains fail "
                      f"it {env.robustness_verdict()}")
        where.append("maglevgen envelope")
    if env.sensing is not None and (why := env.sensing.reason()) is not None:
        failed.append(f"{why} (with {env.sensing.sensors}, across [{env.v_min:.4g}, "
                      f"{env.v_max:.4g}] m/s)")
        where.append("maglevgen envelope")
    for r in runs:
        if r.verdict is not None and not r.verdict.meets:
            failed.append(f"{r.verdict.text()} in the {r.label}")
            where.append(r.command)
    for scale, group in _hold_groups(holds):
        bad_holds = [f"{h.speed:.4g} m/s: " + ", ".join(f)
                     for h in group if (f := h.failures(carriage.params.track.min_gap))]
        if bad_holds:
            failed.append(f"misses issue 49's targets in its noisy holds with the sensor "
                          f"noise x {scale:g} ({'; '.join(bad_holds)})")
            where.append("maglevgen build")
    if bad := _region_failures(region):
        failed.append(f"has no region of attraction confirmed at {', '.join(bad)} m/s (the "
                      "firmware loop does not settle from the boundary of the set)")
        where.append("maglevgen roa")
    if not failed:
        return None
    return (f"{head} " + "; ".join(failed) + f" ({'; '.join(dict.fromkeys(where))}; "
            "--allow-unstable to accept)")


def _hold_groups(holds: tuple[NoisyHold, ...]) -> list[tuple[float, list[NoisyHold]]]:
    """The noisy holds grouped by their noise scale, in order."""
    scales = sorted({h.noise_scale for h in holds})
    return [(sc, [h for h in holds if h.noise_scale == sc]) for sc in scales]


def _hold_lines(holds: tuple[NoisyHold, ...], min_gap: float) -> list[VerdictLine]:
    """The noisy holds as one check: where, how long, in which loop, and the worst numbers
    against issue 49's targets (output_feedback.NoisyHold.failures)."""
    if not holds:
        return []
    speeds = ", ".join(dict.fromkeys(f"{h.speed:.4g}" for h in holds))
    scales = " and ".join(f"x {sc:g}" for sc, _ in _hold_groups(holds))
    subject = (f"noisy holds, {holds[0].t_end:g} s at {speeds} m/s, sensor noise {scales} "
               "(the firmware's sense tick on the plant's noisy readings)")
    bad = [f"x {h.noise_scale:g} at {h.speed:.4g} m/s: " + ", ".join(f)
           for h in holds if (f := h.failures(min_gap))]
    if bad:
        return [VerdictLine(subject, "FAILS issue 49's targets: " + "; ".join(bad), False)]
    shares = ", ".join(f"{100 * max(h.worst_share for h in g):.2g} % (x {sc:g})"
                       for sc, g in _hold_groups(holds))
    at = 100 * max(float(max(h.at_budget)) for h in holds)
    ticks = "no tick" if at == 0 else f"{at:.2g} % of ticks"
    return [VerdictLine(subject, f"meets issue 49's targets: force RMS <= {shares} of the "
                        f"budget, {ticks} at it, smallest gap "
                        f"{1e3 * min(h.min_gap for h in holds):.4g} mm, settled", True)]


def _region_line(region: Region) -> VerdictLine:
    """The region of attraction as one check: confirmed at every speed, and how many times
    the default disturbance fits."""
    speeds = ", ".join(f"{r.speed:.4g}" for r in region.regions)
    subject = (f"region of attraction at {speeds} m/s (a contact-free sublevel set of V on "
               f"which V decreases; its boundary confirmed by {region.loop}-loop runs)")
    bad = _region_failures(region)
    if bad:
        return VerdictLine(subject, f"FAILS: no region confirmed at {', '.join(bad)} m/s",
                           False)
    lo = min(region.regions, key=lambda r: r.disturbance_multiple)
    hi = max(region.regions, key=lambda r: r.disturbance_multiple)
    return VerdictLine(subject, f"confirmed at every speed; the default disturbance fits "
                       f"{lo.disturbance_multiple:.3g}x (at {lo.speed:.4g} m/s) to "
                       f"{hi.disturbance_multiple:.3g}x (at {hi.speed:.4g} m/s)", True)


def embedded_verdict(carriage, env, runs: tuple[JudgedRun, ...] = (),
                     region: Region | None = None, complete: bool = True,
                     holds: tuple[NoisyHold, ...] = ()) -> EmbeddedVerdict:
    """The verdict of the module docstring from the envelope ``env``, the judged ``runs``,
    the embedded controller's ``region`` and its noisy ``holds``
    (maglevgen.analyses.output_feedback); ``complete`` False: the runs and the region were
    not made (the report alone says so instead of a verdict)."""
    from maglevgen.analyses.simulate import DISTURBANCE
    from maglevgen.analyses.worst_case import sign_combinations
    from maglevgen.controllers import title as controller_title

    name = carriage.params.envelope.embedded_controller
    c = env.controllers[name]
    span = f"[{env.v_min:.4g}, {env.v_max:.4g}] m/s"
    checks = [VerdictLine(f"linear, across {span} (the loop as built; {env.model})",
                          f"{c.verdict}; specification: {c.spec_verdict}",
                          bool(c.ok and c.meets_spec))]
    if env.other_models:
        checks.append(VerdictLine("its gains on the other models, across " + span,
                                  env.robustness_verdict(), bool(env.robust)))
    if (sc := env.sensing) is not None:
        checks.append(VerdictLine(sc.verdict_subject(), sc.verdict_text(), bool(sc.ok)))
    n_signs = len(sign_combinations(DISTURBANCE))
    checks += [VerdictLine(f"{r.label} ({r.loop_text()}, worst of {n_signs} disturbance "
                           "sign combinations)", r.verdict.text(), bool(r.verdict.meets))
               for r in runs]
    checks += _hold_lines(holds, carriage.params.track.min_gap)
    if region is not None:
        checks.append(_region_line(region))
    findings = tuple(VerdictLine(f"{controller_title(n)} (`{n}`), linear, across {span}",
                                 f"{e.verdict}; specification: {e.spec_verdict}",
                                 bool(e.ok and e.meets_spec))
                     for n, e in env.controllers.items() if n != name)
    reason = embedded_verification(carriage, env, runs, region, holds)
    # one decision: the lines' and the reason's (both from the same checks)
    assert (reason is None) == all(x.ok for x in checks) or not complete, (reason, checks)
    return EmbeddedVerdict(name, reason, env.checked_on(), float(env.v_min), float(env.v_max),
                           tuple(checks), findings, controller_title(name), complete)


def _verdict_path(carriage, t_end: float, dt: float) -> Path:
    """Where a build leaves its verdict for `firmware`, `fmu` and `report` (the cache: keyed
    by the parameters, the overrides, the toolchain and the runs' t_end and dt)."""
    from maglevgen.infrastructure.cache import default_cache_dir, toolchain_fingerprint

    loaded = carriage.loaded
    key = (ContentHash().text("params", loaded.sha256)
           .text("overrides", "\0".join(loaded.overrides))
           .text("toolchain", toolchain_fingerprint())
           .text("runs", f"{t_end!r} {dt!r}").hexdigest())
    return default_cache_dir() / "verdicts" / f"{key}.json"


def store_verdict(carriage, verdict: EmbeddedVerdict, t_end: float = RUN_T_END,
                  dt: float = RUN_DT) -> None:
    """Keep ``verdict`` for a later `firmware`, `fmu` or `report` (best effort: a cache)."""
    from maglevgen.infrastructure.cache import write_atomic

    path = _verdict_path(carriage, t_end, dt)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    write_atomic(path, json.dumps(verdict.stored()).encode())


def cached_verdict(carriage, t_end: float = RUN_T_END, dt: float = RUN_DT
                   ) -> EmbeddedVerdict | None:
    """The verdict a build of the same parameters (runs of ``t_end`` at ``dt``) left in the
    cache, None when there is none."""
    try:
        return EmbeddedVerdict.from_stored(
            json.loads(_verdict_path(carriage, t_end, dt).read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def verify_embedded(plant: Plant, step: Callable[[str], None] = lambda _: None
                    ) -> EmbeddedVerdict:
    """The embedded controller's verdict, the same check as `build` (its linear spec across
    the envelope on every model, its hold and launch runs on the worst disturbance signs, at
    the build's default t_end and dt, its region of attraction): the one a build of the same
    parameters left in the cache, else computed here (and left for the next)."""
    carriage = plant.carriage
    got = cached_verdict(carriage)
    if got is not None:
        return got
    from maglevgen.analyses import roa
    from maglevgen.analyses.envelope import compute_envelope
    from maglevgen.analyses.sim_loop import flown_loop

    step("verifying the embedded controller against [control.spec] (as `maglevgen build`; "
         "cached afterwards)")
    env = compute_envelope(plant)
    judged = embedded_runs(plant, env, carriage.params.operation.speed)
    name = carriage.params.envelope.embedded_controller
    (region,) = roa.study(plant, [name], roa.BUILD_SPEEDS, roa.BUILD_SAMPLING,
                          flown_loop(plant))
    holds = build_holds(plant, env.v_min, env.v_max)
    verdict = embedded_verdict(carriage, env, judged, region, holds=holds)
    store_verdict(carriage, verdict)
    return verdict



def generate_example(plant: Plant) -> dict:
    """What `maglevgen generate`'s example main.c runs and says: the embedded controller's
    gains at operation.speed (moved into the envelope [v_min, v_max] where it lies outside),
    the speed and the verdict at that speed on the loop the example runs (the controller at
    every RK4 stage of maglev_rk4_step, the propulsion held at the trim drag: the ten-state
    closed loop of eqs 24-33) against [control.spec]'s stability, damping ratio and decay
    rate; the firmware loop's verdict is `maglevgen build`'s (said in the line)."""
    from maglevgen.control.operating import (
        STABILITY_MARGIN,
        Weights,
        closed_loop_stability,
        operating_point,
    )
    from maglevgen.controllers import title as controller_title

    carriage, lib = plant.carriage, plant.lib
    params = carriage.params
    name = params.envelope.embedded_controller
    v_min, v_max = plant.speed_range
    speed = float(min(max(params.operation.speed, v_min), v_max))
    op = operating_point(lib, carriage.p, speed, params.track.min_gap, Weights.of(params))
    K_pos, K_rate = op.gains(name)
    max_real, damping = closed_loop_stability(op, name)
    spec = params.control.spec
    failed = [what for what, ok in (
        ("stability", max_real < -STABILITY_MARGIN),
        (f"damping ratio >= {spec.min_damping_ratio:g}", damping >= spec.min_damping_ratio),
        (f"decay rate >= {spec.min_decay_rate:g} 1/s", -max_real >= spec.min_decay_rate))
        if not ok]
    said = ("meets [control.spec]'s stability, damping ratio and decay rate there" if not failed
            else "FAILS [control.spec]'s " + ", ".join(failed) + " there")
    verdict = (f"{controller_title(name)} ({name}, envelope.embedded_controller) at "
               f"{speed:.4g} m/s, inside the envelope [{v_min:.4g}, {v_max:.4g}] m/s: the "
               "continuous closed loop this example runs (the controller at every RK4 stage, "
               f"the propulsion held) has largest real part {max_real:.4g} 1/s and smallest "
               f"damping ratio {damping:.3g}: {said}; the firmware loop (tick, delay, actuator "
               "lag) is verified by `maglevgen build`")
    return {"controller": name, "title": controller_title(name), "speed": speed,
            "K_pos": _written(K_pos), "K_rate": _written(K_rate),
            "verdict": verdict, "verified": not failed}


def _written(K) -> list[float]:
    """A gain matrix as generated C holds it (column-major): 12 significant digits, and the
    entries below 1e-9 of the largest (round-off of a zero) as 0, so that the generated text
    does not change with the last bits of the linear algebra (BLAS, threads)."""
    import numpy as np

    K = np.asarray(K, dtype=float).ravel(order="F")
    big = float(np.max(np.abs(K))) if K.size else 0.0
    return [0.0 if abs(k) < 1e-9 * big else float(f"{k:.12g}") for k in K]
