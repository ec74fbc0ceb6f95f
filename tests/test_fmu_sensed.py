"""The FMU on the sensors (`maglevgen fmu --loop sensed`, the default for the embedded
controller where the file has [sensors]; maglevgen/exports/fmu_sense.py): the firmware's own
sense tick inside the FMU, on the plant's readings with noise the FMU draws itself.

References: FMPy runs the FMUs; the host's sensed loop (`maglevgen simulate --loop sensed`:
maglev_simulate around the firmware folder compiled for the host, itself held against numpy's
output-feedback loop in test_sensed.py) fed with the noise of an implementation of the FMU's
documented generator written here in plain Python (splitmix64, Marsaglia's polar method:
`_reference_noise`), whose normals SciPy's Kolmogorov-Smirnov test holds against the normal
distribution.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from scipy import stats

from maglevgen.analyses import sim_loop
from maglevgen.analyses.simulate import simulate
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import build_fmu

STATES = [s.name for s in cv.STATES]
T_END = 0.3  # [s]: the disturbance's first ticks, then the loop settling on the readings
MASK = (1 << 64) - 1


class _SplitMix:
    """splitmix64, uniforms in [-1, 1) and Marsaglia's polar normals, as the FMU documents
    them (NOISE_GENERATOR), in Python's integers and floats."""

    def __init__(self, seed: int) -> None:
        self.state = seed & MASK

    def uniform(self) -> float:
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        z ^= z >> 31
        return 2.0 * ((z >> 11) * 2.0**-53) - 1.0

    def normal(self) -> float:
        while True:
            u, v = self.uniform(), self.uniform()
            s = u * u + v * v
            if 0.0 < s < 1.0:
                return u * math.sqrt(-2.0 * math.log(s) / s)


def _reference_noise(var: dict, names: list[str], seed: int, ticks: int,
                     scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(noise (ticks, readings), resolutions) the FMU adds with its start values: each
    reading's bias sign drawn once, in order, then per tick per reading bias + white z."""
    gen = _SplitMix(seed)
    white = [float(var[f"sensor.{n}.noise"].start) * scale for n in names]
    bias = [float(var[f"sensor.{n}.bias"].start) * scale * (-1.0 if gen.uniform() < 0 else 1.0)
            for n in names]
    step = np.array([float(var[f"sensor.{n}.resolution"].start) * scale for n in names])
    noise = np.array([[b + w * gen.normal() for b, w in zip(bias, white, strict=True)]
                      for _ in range(ticks)])
    return noise, step


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, carriage):
    """The embedded controller's FMU with the default loop (both kinds), per FMI version."""
    folder = tmp_path_factory.mktemp("fmu_sensed")
    made: dict[str, Path] = {}

    def get(fmi: str) -> Path:
        if fmi not in made:
            made[fmi] = folder / f"sensed_fmi{fmi}.fmu"
            made[fmi].write_bytes(build_fmu(Plant(carriage), "both", fmi=fmi))
        return made[fmi]

    return get


def _readings(path: Path) -> list[str]:
    return [v.name.removeprefix("reading.") for v in read_model_description(str(path))
            .modelVariables if v.name.startswith("reading.")]


def _host(carriage, sim_lib, op, sensed_tick, noise: np.ndarray, step: np.ndarray,
          monkeypatch):
    """The host's sensed loop of the same controller from the same start, with ``noise``
    (``sensed_tick``: conftest's, `run_loop`'s on the sensors)."""
    tick, k_v, budget = sensed_tick

    def given(params, layout, n_ticks, *args, **kwargs):
        assert n_ticks <= noise.shape[0]
        return noise[:n_ticks], step

    monkeypatch.setattr(sim_loop, "reading_noise", given)
    return simulate(sim_lib, carriage.p, op, carriage.params.envelope.embedded_controller,
                    T_END, 1e-3, carriage.params.track.min_gap, tick=tick, speed_gain=k_v,
                    force_budget=budget)


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_cs_flies_the_hosts_sensed_loop_on_the_same_noise(fmus, carriage, sim_lib, op, fmi,
                                                          sensed_tick, monkeypatch) -> None:
    """Co-simulation: the FMU's states, applied inputs and readings equal the host's sensed
    loop's at every sample, bit for bit, when the host adds the noise of the documented
    generator; another seed flies another run; the default loop is the sensed one."""
    path = fmus(fmi)
    var = {v.name: v for v in read_model_description(str(path)).modelVariables}
    names = _readings(path)
    assert names and "noise_seed" in var  # the default loop of the embedded controller
    ticks = round(T_END * float(var["tick_rate"].start)) + 1
    noise, step = _reference_noise(var, names, 0, ticks)
    ref = _host(carriage, sim_lib, op, sensed_tick, noise, step, monkeypatch)
    assert ref.sensing.tick_error == 0 and len(ref.t) == ticks
    res = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                       output_interval=1e-3,
                       output=[*STATES, "F_prop", *(f"reading.{n}" for n in names)])
    x = np.column_stack([res[n] for n in STATES])
    assert np.array_equal(x, ref.x)
    np.testing.assert_array_equal(res["F_prop"], ref.u[:, 0])
    y = np.column_stack([res[f"reading.{n}"] for n in names])
    np.testing.assert_array_equal(y, ref.sensing.readings[:ticks])
    assert np.ptp(ref.x[:, STATES.index("z")]) > 1e-4  # the disturbance is flown back
    other = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                         output_interval=1e-3, output=STATES, start_values={"noise_seed": 1})
    assert not np.array_equal(np.column_stack([other[n] for n in STATES]), ref.x)


def test_the_generators_normals_are_standard_normal() -> None:
    """The FMU's generator (its reference here, which the FMU equals bit for bit above):
    20000 draws pass SciPy's Kolmogorov-Smirnov test against N(0, 1) and their uniforms
    span [-1, 1)."""
    gen = _SplitMix(7)
    z = np.array([gen.normal() for _ in range(20000)])
    assert stats.kstest(z, "norm").pvalue > 1e-3
    u = np.array([gen.uniform() for _ in range(20000)])
    assert u.min() >= -1.0 and u.max() < 1.0 and abs(u.mean()) < 0.02


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_model_exchange_flies_near_the_cosimulation(fmus, fmi) -> None:
    """Model exchange (CVode, the ticks as time events, the lagged forces as states) flies
    the same loop on the same noise: its heave and pitch within 2 % of the co-simulation's
    excursion (the plant is integrated differently, so a reading can round to the other
    side of a step)."""
    path = fmus(fmi)
    kw = {"stop_time": T_END, "output_interval": 1e-3, "output": STATES}
    cs = simulate_fmu(str(path), fmi_type="CoSimulation", **kw)
    me = simulate_fmu(str(path), fmi_type="ModelExchange", solver="CVode",
                      relative_tolerance=1e-9, **kw)
    for name in ("z", "theta"):
        a, b = cs[name], np.interp(cs["time"], me["time"], me[name])
        assert np.max(np.abs(a - b)) <= 0.02 * np.ptp(a), name


@pytest.mark.parametrize("name, value, says", [
    ("tick_rate", 500.0, "firmware's tick"),
    ("speed_gain", 1.0, "keeps its start value"),
    ("noise_seed", 0.5, "whole seed"),
    ("sensor.gyro_p.noise", -1.0, "finite and >= 0"),
])
def test_a_value_the_firmware_cannot_fly_is_refused_at_initialization(fmus, name, value, says,
                                                                        capsys) -> None:
    """The firmware's tables fix the tick, the delay and the law's gains; the noise's
    parameters must make sense: each bad value fails the initialization with a message."""
    path = fmus("2")
    with pytest.raises(Exception):  # noqa: B017 (FMPy raises its own on the error status)
        simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=0.01,
                     start_values={name: value}, debug_logging=True,
                     logger=lambda *a: print(a[-1].decode() if isinstance(a[-1], bytes)
                                             else a[-1]))
    assert says in capsys.readouterr().out


def test_the_plants_lag_may_change_and_a_noiseless_run_reads_the_plant(fmus) -> None:
    """actuator_lag is the plant's (the firmware keeps its design): a longer lag flies a
    different run; noise_scale = 0 gives readings without noise or rounding: the track
    reading is the track position x at the tick."""
    path = fmus("2")
    base = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=0.05,
                        output_interval=1e-3, output=["z", "x", "reading.track_x"],
                        start_values={"noise_scale": 0.0})
    np.testing.assert_array_equal(base["reading.track_x"][1:], base["x"][1:])
    lagged = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=0.05,
                          output_interval=1e-3, output=["z"],
                          start_values={"noise_scale": 0.0, "actuator_lag": 0.004})
    assert not np.array_equal(base["z"], lagged["z"])


@pytest.mark.slow  # the FMU rebuilt from its sources
def test_the_listed_sources_rebuild_the_sensed_binary(fmus, tmp_path: Path) -> None:
    """The sources the model description lists (the firmware's renamed C among them) and
    FMPy's headers rebuild the binary: in place of the shipped one it flies the same run."""
    import shutil
    import subprocess
    import zipfile

    from maglevgen.exports.fmu import fmi_headers

    path = fmus("2")
    md = read_model_description(str(path))
    unzipped = tmp_path / "fmu"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(unzipped)
    files = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert any(f.startswith("maglev_fw_") for f in files)
    lib = unzipped / "binaries" / "linux64" / "maglev.so"
    kw = {"fmi_type": "CoSimulation", "stop_time": 0.05, "output_interval": 1e-3,
          "output": STATES}
    shipped = simulate_fmu(str(unzipped), **kw)
    lib.unlink()
    cc = shutil.which("gcc") or shutil.which("clang")
    assert cc is not None
    subprocess.run([cc, "-std=c99", "-O2", "-fPIC", "-shared", f"-I{fmi_headers()}",
                    *[str(unzipped / "sources" / f) for f in files], "-o", str(lib), "-lm"],
                   check=True, capture_output=True)
    rebuilt = simulate_fmu(str(unzipped), **kw)
    for name in STATES:
        np.testing.assert_allclose(rebuilt[name], shipped[name], rtol=1e-12, atol=1e-15)
