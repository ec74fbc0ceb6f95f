"""The ``loop`` string exists only at the API and the CLI: `api.arguments.loop_of` turns it into
a `Loop` (or refuses it with the option's one-line message), and below the API a run and an
FMU take the `Loop` and refuse a string before any work (no library is loaded here)."""

from __future__ import annotations

import pytest

from maglevgen.analyses.simulate import run_scenarios
from maglevgen.api.arguments import loop_of
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.errors import InputError
from maglevgen.exports.fmu import FMU_LOOPS, build_fmu


def test_the_api_parses_each_loop_string_to_its_loop() -> None:
    assert [loop_of(s) for s in ("firmware", "sensed", "continuous")] == [
        Loop.FIRMWARE, Loop.SENSED, Loop.CONTINUOUS]
    assert loop_of("continuous", FMU_LOOPS) is Loop.CONTINUOUS


@pytest.mark.parametrize(("text", "choices"), [("fimware", None), ("", None), (None, None),
                                               (1, None), ("ideal", FMU_LOOPS)])
def test_the_api_refuses_other_loops_naming_the_choices(text, choices) -> None:
    with pytest.raises(InputError, match="^--loop .*: expected one of "
                       + (", ".join(choices) if choices else "firmware, sensed, continuous")):
        loop_of(text, choices)


def test_below_the_api_a_loop_string_is_refused(carriage: DerivedCarriage) -> None:
    plant = Plant(carriage)
    with pytest.raises(TypeError, match="a Loop"):
        run_scenarios(plant, ("lqr",), 0.1, 1e-3, loop="firmware")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="a Loop"):
        build_fmu(plant, "cs", "lqr", loop="firmware")  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"flies the embedded controller 'spec'.*not 'lqr'"):
        build_fmu(plant, "cs", "lqr", loop=Loop.SENSED)
    assert not plant.loaded  # refused before the library
