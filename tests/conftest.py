"""Shared fixtures: the default carriage, built once per test session; the tool markers.

The derivation/compile cache goes to a temporary folder made for the run (shared by the
pytest-xdist workers), so the suite neither reads nor writes the user's cache. The run starts
with a cold build of the default carriage into it (`_cold_build`, before pytest-xdist's workers
start; a run in one process derives as it goes):
the workers then read its derivations and libraries instead of deriving them side by side,
and its output is the `default_build` fixture. Tests that corrupt or replace cache entries
work on a copy (`seeded_cache`).

Tool markers (pyproject.toml): ``needs_cc`` (the C compiler, nm and size; extra tools as
arguments, e.g. ``needs_cc("clang")``), ``needs_tex`` (latexmk and pdftotext), ``needs_arm``
(arm-none-eabi-gcc). A test whose tool is missing is skipped with the install command in the
reason and counted at the end of the run; when the environment variable CI is set (CI installs
every tool, .ci/run) the same test fails instead, so CI cannot pass with a check left out.
Tests that use a fixture compiling the generated C get ``needs_cc`` automatically.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.params import load_params

_INSTALL = {
    "needs_cc": "apt-get install -y gcc binutils (or set CC to an installed compiler)",
    "needs_tex": "apt-get install -y --no-install-recommends latexmk texlive-latex-base "
                 "texlive-latex-recommended texlive-fonts-recommended poppler-utils",
    "needs_arm": "apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm",
}
# Fixtures that compile generated C: every test using one needs the compiler.
_CC_FIXTURES = frozenset({"sim_lib", "op", "runtime_lib", "baked"})
_tool_skips: list[str] = []


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def _tools(marker: str, extra: tuple[str, ...]) -> tuple[str, ...]:
    if marker == "needs_cc":
        from maglevgen.runtime.compile import compiler_name

        return (compiler_name(), "nm", "size", *extra)
    return {"needs_tex": ("latexmk", "pdftotext"), "needs_arm": ("arm-none-eabi-gcc",)
            }[marker] + extra


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if _CC_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.needs_cc)


def pytest_runtest_setup(item: pytest.Item) -> None:
    for name, hint in _INSTALL.items():
        extra = tuple(a for m in item.iter_markers(name) for a in m.args)
        if item.get_closest_marker(name) is None:
            continue
        missing = [t for t in dict.fromkeys(_tools(name, extra)) if shutil.which(t) is None]
        if not missing:
            continue
        msg = f"{name}: {', '.join(missing)} not installed; install: {hint}"
        if _in_ci():
            pytest.fail(f"{msg} (CI is set: CI installs every tool, so this is a failure)",
                        pytrace=False)
        _tool_skips.append(item.nodeid)
        pytest.skip(f"TOOL MISSING, CHECK NOT RUN: {msg}")


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    if _tool_skips:
        terminalreporter.write_sep("!", f"{len(_tool_skips)} tests NOT RUN for a missing tool "
                                   "(see the skip reasons; CI=true makes them fail)", red=True)


@pytest.fixture(scope="session")
def carriage() -> DerivedCarriage:
    return DerivedCarriage(load_params())


@pytest.fixture(scope="session")
def trim(carriage: DerivedCarriage):
    return carriage.trim()


_SHARED_CACHE = "MAGLEVGEN_TEST_SHARED_CACHE"


def pytest_configure(config: pytest.Config) -> None:
    """One cache folder for the run, made by the controlling process before pytest-xdist
    starts its workers (they inherit the environment), so a derivation or a compiled
    library built by one worker is read by the others (cache writes are atomic renames)."""
    if hasattr(config, "workerinput") or _SHARED_CACHE in os.environ:
        return
    config._maglev_cache = tempfile.TemporaryDirectory(prefix="maglevgen-cache-")
    os.environ[_SHARED_CACHE] = config._maglev_cache.name
    config._maglev_build = tempfile.TemporaryDirectory(prefix="maglevgen-cold-build-")
    out = os.path.join(config._maglev_build.name, "out")
    # only for workers (pytest-xdist's -n N): one process derives what it needs as it goes,
    # and a run of a few light tests pays for no build
    if getattr(config.option, "numprocesses", None) and _cold_build(
            config._maglev_cache.name, out):
        os.environ[_DEFAULT_BUILD] = out


_DEFAULT_BUILD = "MAGLEVGEN_TEST_DEFAULT_BUILD"
BUILD_FAST = ("--t-end", "1", "--no-pdf")  # the suite's build options: a 1 s run, no PDF


def _cold_build(cache: str, out: str) -> bool:
    """The cold build the suite exercises first: the default carriage built once into the
    run's empty cache, before the workers start, so that they read its derivations and
    libraries instead of deriving the same ones side by side; its output is the
    `default_build` fixture. Its result is judged by the build's own tests; a build that
    fails is printed here, and the tests then build (and fail) on their own."""
    import sys
    import time

    start = time.perf_counter()
    code, lines = timed_run([sys.executable, "-m", "maglevgen.cli", "build", "--out", out,
                             *BUILD_FAST], {**os.environ, "MAGLEVGEN_CACHE": cache})
    # its stderr with each line's time, for test_build's check of the longest silence
    log = os.path.join(os.path.dirname(out), "stderr.json")
    with open(log, "w") as f:
        json.dump({"exit": code, "seconds": time.perf_counter() - start, "lines": lines}, f)
    os.environ[_COLD_LOG] = log
    tail = [line for _, line in lines[-1:]] if code != 0 else []
    sys.stderr.write(f"maglevgen tests: cold build of the default carriage into the run's "
                     f"cache: exit {code} in {time.perf_counter() - start:.0f} s"
                     f"{' (' + tail[0] + ')' if tail else ''}\n")
    return code == 0


_COLD_LOG = "MAGLEVGEN_TEST_COLD_BUILD_LOG"  # the cold build's timestamped stderr (json)


def timed_run(cmd: list[str], env: dict[str, str]) -> tuple[int, list[tuple[float, str]]]:
    """Run ``cmd``; its exit code and its stderr's lines, each with the seconds since the
    start at which it arrived, the process's end last as (t, "")."""
    import subprocess
    import time

    start = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stderr is not None
    lines = [(time.monotonic() - start, line.rstrip("\n")) for line in proc.stderr]
    code = proc.wait()
    return code, [*lines, (time.monotonic() - start, "")]


def pytest_unconfigure(config: pytest.Config) -> None:
    folder = getattr(config, "_maglev_cache", None)
    if folder is not None:
        os.environ.pop(_SHARED_CACHE, None)
        os.environ.pop(_DEFAULT_BUILD, None)
        os.environ.pop(_COLD_LOG, None)
        folder.cleanup()
        config._maglev_build.cleanup()


@pytest.fixture(scope="session", autouse=True)
def private_cache():
    """MAGLEVGEN_CACHE for the whole run (also seen by CLI subprocesses), shared by workers."""
    old = os.environ.get("MAGLEVGEN_CACHE")
    os.environ["MAGLEVGEN_CACHE"] = d = os.environ[_SHARED_CACHE]
    yield d
    if old is None:
        os.environ.pop("MAGLEVGEN_CACHE", None)
    else:
        os.environ["MAGLEVGEN_CACHE"] = old


@pytest.fixture(scope="session")
def default_build(tmp_path_factory, private_cache) -> Path:
    """A complete build of the default carriage (`BUILD_FAST`), made once: the run's cold
    build, or (with MAGLEVGEN_TEST_SHARED_CACHE set) a build made here. Read-only: a test
    that writes into a build works on `copy_build` of it."""
    ready = os.environ.get(_DEFAULT_BUILD)
    if ready and os.path.isdir(ready):
        return Path(ready)
    from maglevgen.cli import main

    out = tmp_path_factory.mktemp("default-build") / "out"
    assert main(["build", "--out", str(out), *BUILD_FAST]) == 0
    return out


@pytest.fixture
def fresh_build(tmp_path: Path, default_build: Path) -> Path:
    """A writable copy of `default_build` (its stamp still matches: the build's key does not
    depend on where it is)."""
    return Path(shutil.copytree(default_build, tmp_path / "out"))


@pytest.fixture
def seeded_cache(tmp_path_factory, private_cache) -> str:
    """A private cache folder holding a copy of the run's cache: a test that corrupts or
    replaces entries starts warm and rebuilds only what it touches."""
    folder = tmp_path_factory.mktemp("seeded") / "cache"
    shutil.copytree(private_cache, folder, ignore=shutil.ignore_patterns(".*"))  # not temp files
    return str(folder)


@pytest.fixture(scope="session")
def sim_lib(carriage: DerivedCarriage, private_cache):
    """The compiled run-time-parameter simulation library of the default carriage."""
    from maglevgen.runtime.library import simulation_library

    return simulation_library(carriage.structure)


@pytest.fixture(scope="session")
def sensed_tick(carriage: DerivedCarriage, sim_lib):
    """`run_loop`'s (tick, speed gain, force budget) of the default carriage on the sensors:
    its firmware rendered and its sense tick compiled for the host, once."""
    from maglevgen.analyses.sim_loop import run_loop
    from maglevgen.control.carriage_plant import Plant

    return run_loop(Plant(carriage, sim_lib), "sensed")


@pytest.fixture(scope="session")
def op(sim_lib, carriage: DerivedCarriage):
    """Trim and gains at the default speed, from the generated C."""
    from maglevgen.analyses.simulate import Weights, operating_point

    return operating_point(sim_lib, carriage.p, carriage.params.operation.speed,
                           carriage.params.track.min_gap, Weights.of(carriage.params))


@pytest.fixture(scope="session")
def rendered():
    """`maglevgen.codegen.generate.render`, once per carriage, options and speed range in a
    process: rendering (the CasADi functions, the C and its checks) takes about 10 s, and the
    code-generation and firmware tests compile or read the same few renders (double and single,
    run-time and baked). Each test writes its own copy; the dict is not to be changed."""
    from maglevgen.codegen.generate import render

    done: dict[tuple, dict[str, str]] = {}

    def get(carriage: DerivedCarriage, opts, speed_range: tuple[float, float] | None = None
            ) -> dict[str, str]:
        # the speed range is baked only with the parameters (render ignores it otherwise)
        key = (carriage.loaded.sha256, carriage.loaded.overrides, opts,
               speed_range if opts.parameters == "baked" else None)
        if key not in done:
            done[key] = render(carriage, opts, speed_range)
        return done[key]

    return get
