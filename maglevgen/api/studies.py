"""The carriage's studies: runs, the envelope, Monte Carlo, the region of attraction."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.api.arguments import (
    MAX_SEED,
    MAX_WORKERS,
    as_path,
    check_controller,
    check_run_arguments,
    chosen_loop,
    commands,
    controller_choice,
    flag,
    initial_disturbance,
    loop_of,
    quiet,
)
from maglevgen.api.core import CarriageCore
from maglevgen.api.results import (
    EnvelopeResult,
    MonteCarloResult,
    RegionResult,
    SimulationResult,
    SimulationRuns,
)
from maglevgen.controllers import names as controller_names
from maglevgen.errors import InputError
from maglevgen.infrastructure import progress as steps  # the commands' progress lines (stdlib only)

if TYPE_CHECKING:
    from maglevgen.analyses.simulate import SimulationRun, Trajectory

__all__ = ["Studies"]


class Studies(CarriageCore):
    """`maglevgen.Carriage`'s studies (``simulate``, ``envelope``, ``montecarlo``, ``roa``)."""

    # ---------------------------------------------------------------- time domain

    def simulate(self, controller: str = "lqr", scenario: str = "hold",
                 speed: float | None = None, t_end: float = 10.0,
                 dt: float = 1e-3, loop: str | None = None,
                 disturbance: Mapping[str, float] | Sequence[str] | None = None
                 ) -> SimulationResult:
        """A closed-loop run in the compiled C, as ``maglevgen simulate`` (figs 3-8).

        From the trim disturbed by 1 mm lateral and heave, 2 mrad roll, pitch and yaw; RK4
        in ``maglev_simulate`` (``hold``: the propulsion at the trim drag, the gains of
        ``speed``) or ``maglev_launch`` (``launch``: from the accelerating trim at
        envelope.v_min to v_max, the gains scheduled with the measured speed, the reference
        and the propulsion those of the accelerating trim at envelope.launch_acceleration).

        Parameters
        ----------
        controller : str, optional
            A registered controller (``maglevgen.controllers.names()``: the paper's ``none``,
            ``damping``, ``lqr`` and ``coupled``, ``spec``, and any registered since; default
            the paper's per-axis LQR).
        scenario : {'hold', 'launch'}, optional
            The run (default hold).
        speed : float, optional
            Forward speed of ``hold`` [m/s]; default ``operation.speed``. Not for ``launch``.
        t_end : float, optional
            Simulated time of ``hold`` [s] (default 10); ``launch`` runs until v_max.
        dt : float, optional
            RK4 step [s] (default 1e-3); refused above RK4's stability limit.
        loop : {'firmware', 'sensed', 'continuous'}, optional
            Default: as a carriage flies, ``sensed`` for the embedded controller where the
            file has ``[sensors]``, else ``firmware``. ``firmware``: the firmware tick's law
            at the tick of
            ``[control.spec]`` with its delay, each controller's gains on the loop as built
            (the ``spec`` design at the tick), the speed loop and the force budget, on the
            plant with the actuator lag of ``[actuators]``, the state measured exactly
            (``--loop``); ``sensed``: the embedded controller as the firmware flies it on the
            sensors of ``[sensors]``: the firmware's own C (its sense tick: the Kalman filter
            and the law over its tables) compiled for the host, on the plant's readings with
            their noise (seeded, reproducible), the lag and the delay; ``continuous``: the
            paper's law at every RK4 stage under the trim propulsion.
        disturbance : mapping of str to float, or sequence of str, optional
            The initial deviation from trim (``--disturbance``): state name to value
            (m, rad, m/s, rad/s; at most 0.1 in magnitude), or ``"STATE=VALUE"`` items; given,
            only these states are disturbed. None: the default disturbance above.

        Returns
        -------
        SimulationResult
            t, x, u, gaps, status, metrics and the column names.

        See Also
        --------
        simulations : several controllers, the files and the reference check.

        Raises
        ------
        maglevgen.InputError
            An unknown controller or scenario, t_end or dt outside their ranges, a step
            above the stability limit, a speed with ``launch``.
        maglevgen.NoTrimError
            No equilibrium at the speed.

        Examples
        --------
        >>> import maglevgen
        >>> run = maglevgen.load().simulate(controller="damping", t_end=10.0)
        >>> run.status, run.x.shape, float(run.t[-1])
        ('settled', (10001, 12), 10.0)
        >>> run.metrics["axes"]["vertical"]["unit"]
        'm'
        """
        check_controller(controller)
        return self.simulations(controller, scenario, speed, t_end, dt, loop,
                                disturbance).runs[controller]

    def simulations(self, controller: str = "all", scenario: str = "hold",
                    speed: float | None = None, t_end: float = 10.0, dt: float = 1e-3,
                    loop: str | None = None,
                    disturbance: Mapping[str, float] | Sequence[str] | None = None,
                    check: bool = False, out: str | Path | None = None,
                    progress: bool = False) -> SimulationRuns:
        """The closed-loop runs of ``maglevgen simulate``: one per controller, the files, the
        reference check (figs 3-8).

        The runs of `simulate`, from the same trim, in the compiled C.

        Parameters
        ----------
        controller : str, optional
            A registered controller or ``"all"`` (default; ``--controller``).
        scenario : {'hold', 'launch'}, optional
            The run (default hold; ``--scenario``).
        speed : float, optional
            Forward speed of ``hold`` [m/s] (``--speed``); default ``operation.speed``.
        t_end : float, optional
            Simulated time of ``hold`` [s] (default 10; ``--t-end``).
        dt : float, optional
            RK4 step [s] (default 1e-3; ``--dt``).
        loop : {'firmware', 'sensed', 'continuous'}, optional
            How each controller runs (``--loop``; see `simulate`; default ``sensed`` for the
            embedded controller alone where the file has ``[sensors]``, else ``firmware``);
            ``sensed`` flies the embedded controller alone (``"all"`` is then that one).
        disturbance : mapping of str to float, or sequence of str, optional
            The initial deviation from trim (``--disturbance``; see `simulate`).
        check : bool, optional
            Also integrate each run with SciPy's adaptive DOP853 (rtol 1e-12) on the
            lambdified SymPy model (``--check``; seconds per run; ``loop='continuous'``
            only): `SimulationResult.check`.
        out : str or pathlib.Path, optional
            Write trajectories.npz, the CSV files, metrics.json, metrics.md and the figures
            there (``--out``).
        progress : bool, optional
            Announce the slow steps (and a speed outside the envelope) on stderr.

        Returns
        -------
        SimulationRuns
            Per controller its `SimulationResult`; the start trim, the files.

        Raises
        ------
        maglevgen.InputError
            An unknown controller or scenario, t_end or dt outside their ranges, a step
            above the stability limit, a speed with ``launch``, a disturbance of an unknown
            state or above 0.1, ``check`` without ``loop='continuous'``.
        maglevgen.NoTrimError
            No equilibrium at the speed.

        Examples
        --------
        >>> import maglevgen
        >>> runs = maglevgen.load().simulations(t_end=0.5, disturbance={"z": 0.002})
        >>> list(runs.runs), runs.scenario
        (['none', 'damping', 'lqr', 'coupled', 'spec'], 'hold')
        >>> float(runs.runs["spec"].x[0, 2] - runs.runs["spec"].x[-1, 2]) > 0
        True
        """
        from maglevgen.analyses.simulate import run_scenarios
        from maglevgen.control.built_loop import Loop, flown_controllers

        if controller != "all":
            check_controller(controller)
        out = None if out is None else as_path("--out", out)
        asked = None if loop is None else loop_of(loop)  # None: as a carriage flies
        if flag("--check", check) and asked is not Loop.CONTINUOUS:
            raise InputError("--check: the DOP853 reference integrates the continuous "
                             "control law; add --loop continuous")
        if speed is not None:
            self._speed(speed)
        check_run_arguments(t_end, dt)
        initial = initial_disturbance(disturbance)  # before the library: bad input is one line
        controllers = controller_names() if controller == "all" else (controller,)
        run_loop = chosen_loop(asked, controllers, self.params)
        controllers = flown_controllers(run_loop, controllers,  # on the sensors: the firmware's one
                                        self.params.envelope.embedded_controller,
                                        all_asked=controller == "all")
        if out is not None:  # after the options: a bad one is the line the user sees
            from maglevgen.infrastructure.output import check_writable

            check_writable(Path(out))  # before any work: a folder of the user's is refused
        # this carriage's plant; its library, when not loaded yet, loads once run_scenarios has
        # checked its options (bad input stays the only line), announced only with progress
        plant = self._plant
        if not plant.loaded:
            from maglevgen.control.carriage_plant import Plant

            plant = self.__dict__["_plant"] = Plant(
                self._carriage, progress=steps.step if progress else quiet)
        run = run_scenarios(plant, controllers, t_end, dt, speed,
                            bar=steps.bar if progress else None, scenario=scenario,
                            disturbance=initial, loop=run_loop)
        paths: tuple[Path, ...] = ()
        if out is not None:
            from maglevgen.analyses.sim_output import render_results
            from maglevgen.codegen.generate import write_output

            files = render_results(run.trajectories, run.input_names,
                                   run.header(self._carriage.loaded.sha256))
            paths = tuple(write_output(files, Path(out)))
        if run.warning and progress:
            steps.step(f"warning: {run.warning}")
        checks: dict[str, dict] = {}
        if check:
            from maglevgen.analyses.reference import reference_check

            if progress:
                steps.step("checking against DOP853 (rtol 1e-12) on the lambdified model")
            for traj in run.trajectories:
                checks[traj.controller] = reference_check(self._carriage.functions,
                                                          self._carriage.p, traj)
        return SimulationRuns(
            runs={t.controller: _simulation_result(run, t, checks.get(t.controller))
                  for t in run.trajectories},
            scenario=run.scenario, speed=run.op.speed, propulsion_force=run.op.f_prop,
            release_speed=run.v_end, dt_limit=run.dt_limit, warning=run.warning, paths=paths)

    def envelope(self, n_speeds: int | None = None, out: str | Path | None = None,
                 progress: bool = False) -> EnvelopeResult:
        """Each controller's closed-loop stability across [v_min, v_max], with verdicts.

        The eigenvalues of the ten-state linearisation (`linearize` with
        ``model='reduced'``) with each controller closed around it (`gains`), at evenly
        spaced speeds; the edges of an unstable range located by bisection.

        Parameters
        ----------
        n_speeds : int, optional
            Speeds spanning the envelope (``--speeds``; default 50).
        out : str or pathlib.Path, optional
            Also write envelope.json, envelope.md and stability_map.png there (``--out``).
        progress : bool, optional
            Announce the computation on stderr once the arguments are checked.

        Returns
        -------
        EnvelopeResult
            Per controller the largest real part, smallest damping, verdict and unstable
            ranges.

        Raises
        ------
        maglevgen.InputError
            n_speeds outside 2 to 100000, an envelope with no trim at one of its ends.

        Examples
        --------
        >>> import maglevgen
        >>> env = maglevgen.load().envelope(n_speeds=10)
        >>> env.speeds.size, sorted(env.verdicts)
        (10, ['coupled', 'damping', 'lqr', 'none', 'spec'])
        >>> env.verdicts["coupled"][:6]
        'stable'
        """
        from maglevgen.analyses.envelope import DEFAULT_SPEEDS, MAX_SPEEDS
        from maglevgen.params import check_count

        queries = commands()
        out = None if out is None else as_path("--out", out)
        if n_speeds is not None:  # 0 is refused, not the default
            check_count("--speeds", n_speeds, 2, MAX_SPEEDS, "speeds spanning the envelope")
        if out is not None:
            from maglevgen.infrastructure.output import check_writable

            check_writable(Path(out))  # before any work: a folder of the user's is refused
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce("envelope: each controller's closed-loop eigenvalues at "
                           f"{n_speeds or DEFAULT_SPEEDS} speeds")
        env = queries.envelope_of(self._plant, n_speeds)
        rep = env.to_json()
        paths: tuple[Path, ...] = ()
        if out is not None:
            from maglevgen.analyses.envelope import envelope_markdown
            from maglevgen.analyses.envelope_figures import stability_map_png
            from maglevgen.infrastructure.output import write_output

            paths = tuple(write_output({"envelope.json": json.dumps(rep, indent=1) + "\n",
                                        "envelope.md": envelope_markdown(env),
                                        "stability_map.png": stability_map_png(env)},
                                       Path(out)))
        c = env.controllers
        return EnvelopeResult(
            speeds=env.speeds, v_min=env.v_min, v_max=env.v_max,
            max_real={n: e.max_real for n, e in c.items()},
            min_damping={n: e.min_damping for n, e in c.items()},
            stable={n: e.stable for n, e in c.items()},
            unstable_ranges={n: e.unstable_ranges for n, e in c.items()},
            verdicts={n: e.verdict for n, e in c.items()}, speed_pole=env.speed_pole,
            paths=paths, report=rep,
            lines=tuple(queries.verdict_lines(env, self.params.envelope.embedded_controller)))

    def montecarlo(self, samples: int = 1000, seed: int = 0, controller: str | None = None,
                   t_end: float = 10.0, dt: float = 1e-3, workers: int | None = None,
                   scheduler: str | None = None, out: str | Path | None = None,
                   loop: str | None = None, progress: bool = False,
                   redesign: bool = False) -> MonteCarloResult:
        """Monte-Carlo robustness over the parameter file's ``[tolerances]``, as
        ``maglevgen montecarlo``.

        Each sample draws the toleranced parameters, a speed and an initial disturbance from
        its own ``numpy.random.SeedSequence(seed, spawn_key=(i,))``, so the results do not
        depend on the worker count; the compiled C trims the sample (eqs 1-4, 8-12) and runs
        the closed loop (RK4) of every controller asked for, designed (eqs 20-33) on the
        nominal carriage at the sample's speed, as the firmware flies (``redesign``: on the
        sample's own parameters instead).

        Parameters
        ----------
        samples : int, optional
            Number of sampled carriages (default 1000).
        seed : int, optional
            Seed of the study (default 0).
        controller : str, optional
            A registered controller (``"spec"``, ``"coupled"``, ...) or ``"all"``; default the
            embedded controller (``envelope.embedded_controller``).
        t_end : float, optional
            Length of each run in s (default 10).
        dt : float, optional
            RK4 step in s (default 1e-3).
        workers : int, optional
            Local processes (default every core) or Dask workers of a ``"local"`` cluster.
        scheduler : str, optional
            ``None`` (local processes), ``"local"`` (a Dask LocalCluster) or the address of
            an existing Dask scheduler (``"tcp://host:8786"``).
        out : str or pathlib.Path, optional
            Folder for ``samples.parquet``, ``montecarlo.md``/``.json`` and the plots.
        loop : {'firmware', 'sensed', 'continuous'}, optional
            How every run executes its controller (``--loop``; see `simulate`; default
            ``sensed`` for the embedded controller where the file has ``[sensors]`` and
            ``redesign`` is not asked, else ``firmware``); ``sensed``: the embedded
            controller's sense tick on each sampled carriage, the sensor noise of each sample
            from ``SeedSequence(seed, spawn_key=(i, 1))`` (not with ``redesign``).
        progress : bool, optional
            Announce the study once the arguments are checked, the slow steps on stderr,
            and the runs' rate (a progress bar on a terminal).
        redesign : bool, optional
            Re-design each sample's controller for its own parameters, as if the firmware
            knew them (``--redesign``; default False: the nominal design, as flown).

        Returns
        -------
        MonteCarloResult
            The summary ``maglevgen montecarlo --json`` prints (read as a mapping): per
            controller the contact probability with its 95 % Wilson interval, status counts,
            per-axis quantiles, the worst samples and the inputs the failures correlate with;
            and the files written.

        Raises
        ------
        maglevgen.InputError
            A bad option (the CLI's one-line message), or an unreachable scheduler.

        Examples
        --------
        >>> import maglevgen
        >>> s = maglevgen.load().montecarlo(samples=4, seed=1, t_end=0.5, workers=1)
        >>> sorted(s["controllers"])
        ['spec']
        """
        from maglevgen.analyses.montecarlo import (
            MAX_SAMPLES,
            check_scheduler,
            default_workers,
            make_study,
            output_files,
            run_study,
        )
        from maglevgen.analyses.simulate import run_loop
        from maglevgen.control.built_loop import Loop, flown_controllers
        from maglevgen.infrastructure.output import check_writable, write_output
        from maglevgen.params import check_count

        choice = controller_choice(controller, self.params.envelope.embedded_controller)
        check_count("--samples", samples, 1, MAX_SAMPLES, "the samples' table is held in "
                    "memory")
        check_count("--seed", seed, 0, MAX_SEED, "numpy's SeedSequence takes non-negative "
                    "integers")
        if workers is not None:
            check_count("--workers", workers, 1, MAX_WORKERS, "a process per worker")
        check_run_arguments(t_end, dt)
        asked = None if loop is None else loop_of(loop)  # None: as a carriage flies
        check_scheduler(scheduler)
        controllers = controller_names() if choice == "all" else (choice,)
        if asked is None and redesign:  # a re-design per sample is not what the firmware flies
            asked = Loop.FIRMWARE
        run = chosen_loop(asked, controllers, self.params)
        controllers = flown_controllers(run, controllers, self.params.envelope.embedded_controller,
                                        all_asked=choice == "all")
        if run is Loop.SENSED and redesign:
            raise InputError("--redesign with --loop sensed: the firmware's tables are the "
                             "nominal carriage's (a re-design per sample is not flown)")
        if out is not None:  # after the options: a bad one is the line the user sees
            out = as_path("--out", out)
            check_writable(out)
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce(f"montecarlo: {samples} samples over [tolerances], the compiled "
                           "library and the study first")
        study = make_study(self._plant, controllers, t_end, dt, seed,
                           *run_loop(self._plant, run),
                           redesign=flag("--redesign", redesign))
        k = len(controllers)
        if progress:
            with steps.rate_bar("Monte Carlo", samples * k) as tick:
                result = run_study(study, samples, workers or default_workers(), scheduler,
                                   tick=lambda n: tick(n * k))
        else:
            result = run_study(study, samples, workers or default_workers(), scheduler)
        paths: tuple[Path, ...] = ()
        if out is not None:
            paths = tuple(write_output(output_files(result), Path(out)))
        return MonteCarloResult(result.summary, paths)

    def roa(self, n_speeds: int | None = None, controller: str | None = None,
            samples: int | None = None, seed: int = 0, workers: int = 1,
            batch: int | None = None, out: str | Path | None = None,
            progress: bool = False) -> RegionResult:
        """A sampled region of attraction per speed, as ``maglevgen roa``.

        V = dx' P dx on the ten reduced states (P from the design's Lyapunov / Riccati
        equation); the largest level c with dV/dt < 0 on the nonlinear closed loop (the
        generated C, batched in ``maglev_lyapunov_batch``) and every gap above track.min_gap
        at every sampled state of {V <= c}, then confirmed by closed-loop runs from states
        on {V = c} (`maglevgen.analyses.roa`): as a carriage flies, the firmware's sense tick
        on noisy readings for the embedded controller alone where the file has [sensors],
        else the firmware loop on the exact state. A sampled estimate, not a proof.

        Parameters
        ----------
        n_speeds : int, optional
            Speeds spanning [v_min, v_max] (``--speeds``; default 8).
        controller : str, optional
            A registered controller or ``"all"`` (``--controller``); default the embedded one.
        samples : int, optional
            Random directions per speed (``--samples``; default 3000).
        seed : int, optional
            Seed of the directions (``--seed``).
        workers : int, optional
            Threads evaluating the batches (``--workers``); the numbers do not change.
        batch : int, optional
            States per C call (``--batch``); the numbers do not change.
        out : str or pathlib.Path, optional
            Also write roa.json, roa.md and roa_extent.png there (``--out``).
        progress : bool, optional
            Announce the sampling on stderr once the arguments are checked.

        Returns
        -------
        RegionResult
            Per controller and speed the level, the extents and the default's multiple.

        Raises
        ------
        maglevgen.InputError
            A bad option (the CLI's one-line message).

        Examples
        --------
        >>> import maglevgen
        >>> r = maglevgen.load().roa(n_speeds=2, samples=50)
        >>> sorted(r.levels)
        ['spec']
        """
        from maglevgen.analyses import roa
        from maglevgen.infrastructure.output import check_writable, write_output
        from maglevgen.params import check_count

        choice = controller_choice(controller, self.params.envelope.embedded_controller)
        if n_speeds is not None:
            check_count("--speeds", n_speeds, 1, roa.MAX_SPEEDS, "speeds spanning the "
                        "envelope")
        if samples is not None:
            check_count("--samples", samples, 1, roa.MAX_DIRECTIONS, "directions per speed, "
                        "held in memory")
        if batch is not None:
            check_count("--batch", batch, 1, roa.MAX_BATCH, "states per C call, held in "
                        "memory")
        check_count("--seed", seed, 0, MAX_SEED, "numpy's SeedSequence takes non-negative "
                    "integers")
        check_count("--workers", workers, 1, MAX_WORKERS, "a thread per worker")
        out = None if out is None else as_path("--out", out)
        base = roa.COMMAND_SAMPLING
        sampling = roa.Sampling(directions=base.directions if samples is None else samples,
                                radii=base.radii, bisections=base.bisections,
                                confirm=base.confirm, seed=seed,
                                batch=base.batch if batch is None else batch, workers=workers)
        if out is not None:
            check_writable(Path(out))
        if progress:  # once the arguments are checked: a bad one stays the only line
            steps.announce(f"roa: sampling the region of attraction of {choice} at "
                           f"{n_speeds or roa.DEFAULT_SPEEDS} speeds, "
                           f"{sampling.directions} directions each")
        controllers = controller_names() if choice == "all" else (choice,)
        regions = roa.study(self._plant, controllers,
                            roa.DEFAULT_SPEEDS if n_speeds is None else n_speeds, sampling,
                            chosen_loop(None, controllers, self.params))
        paths: tuple[Path, ...] = ()
        if out is not None:
            paths = tuple(write_output(roa.study_files(regions), Path(out)))
        return RegionResult(
            speeds=regions[0].speeds,
            levels={r.controller: np.array([s.level for s in r.regions]) for r in regions},
            extents={r.controller: {a: np.array([s.extents[a] for s in r.regions])
                                    for a in roa.AXIS_NAMES} for r in regions},
            disturbance_multiple={r.controller: np.array([s.disturbance_multiple
                                                          for s in r.regions])
                                  for r in regions},
            statement=regions[0].statement(), paths=paths, report=roa.study_json(regions),
            lines=tuple(roa.study_lines(regions, self.params.envelope.embedded_controller)))


def _simulation_result(run: SimulationRun, traj: Trajectory,
                       check: dict | None) -> SimulationResult:
    """One run of a `SimulationRun`, with the CSV file's column names."""
    from maglevgen.analyses.sim_output import columns
    from maglevgen.analyses.simulate import metrics, spec_verdict

    verdict = spec_verdict(traj)
    cols = columns(run.input_names, traj.gaps.shape[1])
    names = [n for n, _ in cols]
    n_x, n_u = traj.x.shape[1], traj.u.shape[1]
    return SimulationResult(
        controller=traj.controller, scenario=traj.scenario, t=traj.t, x=traj.x, u=traj.u,
        gaps=traj.gaps, status=traj.status, event=traj.event, metrics=metrics(traj),
        state_names=tuple(names[1:1 + n_x]), input_names=tuple(names[1 + n_x:1 + n_x + n_u]),
        gap_names=tuple(names[1 + n_x + n_u:]), units=dict(cols), dt_limit=run.dt_limit,
        specification=None if verdict is None else verdict.text(), check=check)
