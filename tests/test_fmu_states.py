"""The FMUs follow the FMI state machines (issue 54): every (state, call) pair of a table
typed here from the standard (FMI 2.0.4 sections 3.2.3 and 4.2.4: the functions a state
allows) through FMPy's low-level API in a child process (a crash is a failure of the case,
not of the run): a call the state allows is not answered fmi2Error, one it forbids is
answered fmi2Error with a message through the logger; an error is sticky (only the getters,
fmi2Reset and fmi2FreeInstance after it); co-simulation time is monotone and without gaps;
a NaN start time is refused.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("fmpy")

# the states, the way the driver reaches each from a fresh instance
STATES_CS = ("instantiated", "initialization", "step", "terminated", "error")
STATES_ME = ("instantiated", "initialization", "event", "continuous", "terminated", "error")

# FMI 2.0.4, co-simulation (4.2.4): the states each call is allowed in
ALLOWED_CS = {
    "setupExperiment": {"instantiated"},
    "enterInitializationMode": {"instantiated"},
    "exitInitializationMode": {"initialization"},
    "doStep": {"step"},
    "terminate": {"step"},
    "setReal_input": {"instantiated", "initialization", "step"},
    "getReal_output": {"initialization", "step", "terminated", "error"},
    "reset": set(STATES_CS),
    # model exchange's own calls: never on a co-simulation instance
    "setTime": set(), "setContinuousStates": set(), "getDerivatives": set(),
    "enterContinuousTimeMode": set(), "completedIntegratorStep": set(),
}
# FMI 2.0.4, model exchange (3.2.3)
ALLOWED_ME = {
    "setupExperiment": {"instantiated"},
    "enterInitializationMode": {"instantiated"},
    "exitInitializationMode": {"initialization"},
    "terminate": {"event", "continuous"},
    "setReal_input": {"instantiated", "initialization", "event", "continuous"},
    "getReal_output": {"initialization", "event", "continuous", "terminated", "error"},
    "reset": set(STATES_ME),
    "setTime": {"event", "continuous"},
    "setContinuousStates": {"continuous"},
    "getDerivatives": {"event", "continuous", "terminated", "error"},
    "getContinuousStates": {"event", "continuous", "terminated", "error"},
    "enterContinuousTimeMode": {"event"},
    "newDiscreteStates": {"event"},
    "completedIntegratorStep": {"continuous"},
    "doStep": set(),  # co-simulation's
}

_DRIVER = r'''
import ctypes, json, sys
from ctypes import byref
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Model, FMU2Slave, fmi2CallbackAllocateMemoryTYPE,
                       fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE, fmi2EventInfo, fmi2Boolean)
from fmpy.logging import addLoggerProxy

path = sys.argv[1]
cases = json.loads(sys.argv[2])
md = read_model_description(path)
unzipped = extract(path)
log = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda *a: log.append(a[-1].decode()))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(byref(cb))
inp = next(v.valueReference for v in md.modelVariables if v.causality == "input")
out = next(v.valueReference for v in md.modelVariables if v.causality == "output")
nx = md.numberOfContinuousStates
Vec = ctypes.c_double * nx
loaded = {
    "cs": FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s"),
    "me": FMU2Model(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.modelExchange.modelIdentifier, instanceName="m"),
}

def raw(fmu, name, *args):
    # an FMI function by its symbol, whatever kind of instance FMPy made
    f = getattr(fmu.dll, name)
    f.restype = ctypes.c_int
    return f(ctypes.c_void_p(fmu.component), *args)

def status(f):
    try:
        f()
        return 0
    except FMICallException as exc:
        return exc.status

def run(kind, state, call):
    fmu = loaded[kind]
    fmu.instantiate(callbacks=cb)
    t = 0.0
    if state != "instantiated":
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    if state not in ("instantiated", "initialization"):
        fmu.exitInitializationMode()
        if kind == "cs":
            fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
            t = 1e-3
    if state == "continuous":
        fmu.enterContinuousTimeMode()
    if state == "terminated":
        fmu.terminate()
    if state == "error":
        status(lambda: fmu.setReal([inp], [float("nan")]))
    got = Vec()
    if kind == "me" and state in ("event", "continuous"):  # the states to set back
        raw(fmu, "fmi2GetContinuousStates", got, ctypes.c_size_t(nx))
    log.clear()
    calls = {
        "setupExperiment": lambda: status(lambda: fmu.setupExperiment(startTime=0.0)),
        "enterInitializationMode": lambda: status(fmu.enterInitializationMode),
        "exitInitializationMode": lambda: status(fmu.exitInitializationMode),
        "terminate": lambda: status(fmu.terminate),
        "setReal_input": lambda: status(lambda: fmu.setReal([inp], [0.0])),
        "getReal_output": lambda: status(lambda: fmu.getReal([out])),
        "reset": lambda: status(fmu.reset),
        "doStep": lambda: raw(fmu, "fmi2DoStep", ctypes.c_double(t), ctypes.c_double(1e-3),
                              fmi2Boolean(1)),
        "setTime": lambda: raw(fmu, "fmi2SetTime", ctypes.c_double(0.0)),
        "setContinuousStates": lambda: raw(fmu, "fmi2SetContinuousStates", got,
                                           ctypes.c_size_t(nx)),
        "getDerivatives": lambda: raw(fmu, "fmi2GetDerivatives", Vec(), ctypes.c_size_t(nx)),
        "getContinuousStates": lambda: raw(fmu, "fmi2GetContinuousStates", Vec(),
                                           ctypes.c_size_t(nx)),
        "enterContinuousTimeMode": lambda: raw(fmu, "fmi2EnterContinuousTimeMode"),
        "newDiscreteStates": lambda: raw(fmu, "fmi2NewDiscreteStates",
                                         byref(fmi2EventInfo())),
        "completedIntegratorStep": lambda: raw(fmu, "fmi2CompletedIntegratorStep",
                                               fmi2Boolean(1), byref(fmi2Boolean()),
                                               byref(fmi2Boolean())),
    }
    result = calls[call]()
    messages = list(log)
    after = status(lambda: fmu.getReal([out]))  # what the instance still answers
    fmu.fmi2FreeInstance(fmu.component)
    return {"case": [kind, state, call], "status": result, "log": messages, "after": after}

for kind, state, call in cases:
    print(json.dumps({"start": [kind, state, call]}), flush=True)
    print(json.dumps(run(kind, state, call)), flush=True)
'''

ERROR = 3  # fmi2Error


@pytest.fixture(scope="module")
def fmu_both(carriage, tmp_path_factory) -> Path:
    from maglevgen.control.built_loop import Loop
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.exports.fmu import build_fmu

    path = tmp_path_factory.mktemp("fmu") / "both.fmu"
    path.write_bytes(build_fmu(Plant(carriage), "both", "lqr", loop=Loop.CONTINUOUS))
    return path


def _drive(fmu: Path, cases: list[tuple[str, str, str]]) -> list[dict]:
    """Every case in one child process, each on a fresh instance; a crash names its case."""
    done = subprocess.run([sys.executable, "-c", _DRIVER, str(fmu), json.dumps(cases)],
                          capture_output=True, text=True, timeout=900)
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    results = [r for r in lines if "case" in r]
    if done.returncode != 0:
        last = lines[-1].get("start") if lines else None
        pytest.fail(f"the child ended with {done.returncode} in the case {last}: "
                    f"{done.stderr[-1500:]}")
    return results


# the standard's table leaves these to the FMU (the state derivatives in initialization mode
# as an initial equation's value): not judged here
OPEN = {("me", "initialization", "getDerivatives"), ("me", "initialization",
                                                      "getContinuousStates")}
CASES = [c for c in
         [("cs", s, c, s in allowed) for c, allowed in ALLOWED_CS.items() for s in STATES_CS]
         + [("me", s, c, s in allowed) for c, allowed in ALLOWED_ME.items() for s in STATES_ME]
         if c[:3] not in OPEN]


@pytest.mark.needs_cc
def test_every_state_and_call_of_fmi2(fmu_both: Path) -> None:
    results = _drive(fmu_both, [c[:3] for c in CASES])
    assert len(results) == len(CASES)
    wrong = []
    for (kind, state, call, allowed), res in zip(CASES, results, strict=True):
        if allowed and res["status"] == ERROR:
            wrong.append(f"{kind} {state} {call}: refused ({res['log'][-1:]})")
        if not allowed:
            if res["status"] != ERROR:
                wrong.append(f"{kind} {state} {call}: answered {res['status']}, not fmi2Error")
            elif not res["log"]:
                wrong.append(f"{kind} {state} {call}: fmi2Error without a message")
            elif state != "instantiated" and res["after"] != 0:
                # the error state the call leaves allows the getters
                wrong.append(f"{kind} {state} {call}: getReal after the error: {res['after']}")
    assert wrong == [], "\n".join(wrong)


_SEQUENCES = r'''
import ctypes, json, math, sys
from ctypes import byref
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.logging import addLoggerProxy

path = sys.argv[1]
md = read_model_description(path)
unzipped = extract(path)
log = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda *a: log.append(a[-1].decode()))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(byref(cb))
fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s")
res = {}

def status(f):
    try:
        f()
        return 0
    except FMICallException as exc:
        return exc.status

def fresh():
    fmu.instantiate(callbacks=cb)

fresh()
res["nan start"] = status(lambda: fmu.setupExperiment(startTime=float("nan")))
fmu.fmi2FreeInstance(fmu.component)
for name, t in (("backwards", 0.0), ("jump", 0.5), ("tiny gap", 1e-3 + 1e-6)):
    fresh()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
    res[name] = status(lambda: fmu.doStep(currentCommunicationPoint=t,
                                          communicationStepSize=1e-3))
    res[name + " then step"] = status(lambda: fmu.doStep(currentCommunicationPoint=1e-3,
                                                         communicationStepSize=1e-3))
    res[name + " then reset"] = status(fmu.reset)
    fmu.fmi2FreeInstance(fmu.component)
# the next step from where the last ended: fine, twice
fresh()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
res["in order"] = [status(lambda k=k: fmu.doStep(currentCommunicationPoint=k * 1e-3,
                                                 communicationStepSize=1e-3))
                   for k in range(3)]
fmu.fmi2FreeInstance(fmu.component)
print(json.dumps(res))
'''


@pytest.mark.needs_cc
def test_co_simulation_time_is_monotone_and_a_nan_start_is_refused(fmu_both: Path) -> None:
    done = subprocess.run([sys.executable, "-c", _SEQUENCES, str(fmu_both)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    res = json.loads(done.stdout.strip().splitlines()[-1])
    assert res["nan start"] == ERROR
    for name in ("backwards", "jump", "tiny gap"):
        assert res[name] == ERROR, (name, res)
        assert res[name + " then step"] == ERROR, (name, res)  # the error is sticky
        assert res[name + " then reset"] == 0, (name, res)
    assert res["in order"] == [0, 0, 0]


# ---------------------------------------------------------------------------------- FMI 3.0

# FMI 3.0.1, co-simulation without event mode (4.2) and model exchange (3.2)
ALLOWED3_CS = {
    "enterInitializationMode": {"instantiated"},
    "exitInitializationMode": {"initialization"},
    "doStep": {"step"},
    "terminate": {"step"},
    "setFloat64_input": {"instantiated", "initialization", "step"},
    "getFloat64_output": {"initialization", "step", "terminated", "error"},
    "reset": set(STATES_CS),
    "setTime": set(), "setContinuousStates": set(), "getContinuousStateDerivatives": set(),
    "enterContinuousTimeMode": set(), "completedIntegratorStep": set(),
}
ALLOWED3_ME = {
    "enterInitializationMode": {"instantiated"},
    "exitInitializationMode": {"initialization"},
    "terminate": {"event", "continuous"},
    "setFloat64_input": {"instantiated", "initialization", "event", "continuous"},
    "getFloat64_output": {"initialization", "event", "continuous", "terminated", "error"},
    "reset": set(STATES_ME),
    "setTime": {"event", "continuous"},
    "setContinuousStates": {"continuous"},
    "getContinuousStateDerivatives": {"event", "continuous", "terminated", "error"},
    "getContinuousStates": {"event", "continuous", "terminated", "error"},
    "enterContinuousTimeMode": {"event"},
    "updateDiscreteStates": {"event"},
    "completedIntegratorStep": {"continuous"},
    "doStep": set(),
}
OPEN3 = {("me", "initialization", "getContinuousStateDerivatives"),
         ("me", "initialization", "getContinuousStates")}
CASES3 = [c for c in
          [("cs", s, c, s in allowed) for c, allowed in ALLOWED3_CS.items() for s in STATES_CS]
          + [("me", s, c, s in allowed) for c, allowed in ALLOWED3_ME.items()
             for s in STATES_ME]
          if c[:3] not in OPEN3]

_DRIVER3 = r'''
import ctypes, json, sys
from ctypes import byref, c_bool, c_double, c_size_t, c_uint32, c_void_p
from fmpy import extract, read_model_description
from fmpy.fmi3 import FMU3Model, FMU3Slave

path = sys.argv[1]
cases = json.loads(sys.argv[2])
md = read_model_description(path)
unzipped = extract(path)
log = []
inp = next(v.valueReference for v in md.modelVariables if v.causality == "input")
out = next(v.valueReference for v in md.modelVariables if v.causality == "output")
nx = md.numberOfContinuousStates
Vec = c_double * nx
loaded = {
    "cs": FMU3Slave(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s"),
    "me": FMU3Model(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.modelExchange.modelIdentifier, instanceName="m"),
}

def raw(fmu, name, *args):
    f = getattr(fmu.dll, name)
    f.restype = ctypes.c_int
    return f(c_void_p(fmu.component), *args)

def set64(fmu, value):
    return raw(fmu, "fmi3SetFloat64", byref(c_uint32(inp)), c_size_t(1),
               byref(c_double(value)), c_size_t(1))

def get64(fmu):
    return raw(fmu, "fmi3GetFloat64", byref(c_uint32(out)), c_size_t(1), byref(c_double()),
               c_size_t(1))

def step(fmu, t):
    b = [c_bool() for _ in range(3)]
    return raw(fmu, "fmi3DoStep", c_double(t), c_double(1e-3), c_bool(True), byref(b[0]),
               byref(b[1]), byref(b[2]), byref(c_double()))

def run(kind, state, call):
    fmu = loaded[kind]
    fmu.instantiate(logMessage=lambda env, status, cat, msg: log.append(msg.decode()))
    t = 0.0
    if state != "instantiated":
        raw(fmu, "fmi3EnterInitializationMode", c_bool(False), c_double(0), c_double(0),
            c_bool(False), c_double(0))
    if state not in ("instantiated", "initialization"):
        raw(fmu, "fmi3ExitInitializationMode")
        if kind == "cs":
            step(fmu, 0.0)
            t = 1e-3
    if state == "continuous":
        raw(fmu, "fmi3EnterContinuousTimeMode")
    if state == "terminated":
        raw(fmu, "fmi3Terminate")
    if state == "error":
        set64(fmu, float("nan"))
    got = Vec()
    if kind == "me" and state in ("event", "continuous"):
        raw(fmu, "fmi3GetContinuousStates", got, c_size_t(nx))
    log.clear()
    b = [c_bool() for _ in range(5)]
    calls = {
        "enterInitializationMode": lambda: raw(fmu, "fmi3EnterInitializationMode", c_bool(False),
                                               c_double(0), c_double(0), c_bool(False),
                                               c_double(0)),
        "exitInitializationMode": lambda: raw(fmu, "fmi3ExitInitializationMode"),
        "doStep": lambda: step(fmu, t),
        "terminate": lambda: raw(fmu, "fmi3Terminate"),
        "setFloat64_input": lambda: set64(fmu, 0.0),
        "getFloat64_output": lambda: get64(fmu),
        "reset": lambda: raw(fmu, "fmi3Reset"),
        "setTime": lambda: raw(fmu, "fmi3SetTime", c_double(0.0)),
        "setContinuousStates": lambda: raw(fmu, "fmi3SetContinuousStates", got, c_size_t(nx)),
        "getContinuousStateDerivatives": lambda: raw(fmu, "fmi3GetContinuousStateDerivatives",
                                                     Vec(), c_size_t(nx)),
        "getContinuousStates": lambda: raw(fmu, "fmi3GetContinuousStates", Vec(),
                                           c_size_t(nx)),
        "enterContinuousTimeMode": lambda: raw(fmu, "fmi3EnterContinuousTimeMode"),
        "updateDiscreteStates": lambda: raw(fmu, "fmi3UpdateDiscreteStates", *map(byref, b),
                                            byref(c_double())),
        "completedIntegratorStep": lambda: raw(fmu, "fmi3CompletedIntegratorStep", c_bool(True),
                                               byref(b[0]), byref(b[1])),
    }
    result = calls[call]()
    messages = list(log)
    after = get64(fmu)
    fmu.dll.fmi3FreeInstance(c_void_p(fmu.component))
    return {"case": [kind, state, call], "status": result, "log": messages, "after": after}

for kind, state, call in cases:
    print(json.dumps({"start": [kind, state, call]}), flush=True)
    print(json.dumps(run(kind, state, call)), flush=True)
'''


@pytest.fixture(scope="module")
def fmu3_both(carriage, tmp_path_factory) -> Path:
    from maglevgen.control.built_loop import Loop
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.exports.fmu import build_fmu

    path = tmp_path_factory.mktemp("fmu3") / "both.fmu"
    path.write_bytes(build_fmu(Plant(carriage), "both", "lqr", fmi="3", loop=Loop.CONTINUOUS))
    return path


def _judge(cases: list, results: list[dict]) -> list[str]:
    """The cases whose answer the standard's table does not allow (fmi2Error = fmi3Error = 3)."""
    assert len(results) == len(cases)
    wrong = []
    for (kind, state, call, allowed), res in zip(cases, results, strict=True):
        if allowed and res["status"] == ERROR:
            wrong.append(f"{kind} {state} {call}: refused ({res['log'][-1:]})")
        if not allowed:
            if res["status"] != ERROR:
                wrong.append(f"{kind} {state} {call}: answered {res['status']}, not Error")
            elif not res["log"]:
                wrong.append(f"{kind} {state} {call}: Error without a message")
            elif state != "instantiated" and res["after"] != 0:
                wrong.append(f"{kind} {state} {call}: the getter after the error: "
                             f"{res['after']}")
    return wrong


@pytest.mark.needs_cc
def test_every_state_and_call_of_fmi3(fmu3_both: Path) -> None:
    done = subprocess.run([sys.executable, "-c", _DRIVER3, str(fmu3_both),
                           json.dumps([c[:3] for c in CASES3])],
                          capture_output=True, text=True, timeout=900)
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0:
        last = lines[-1].get("start") if lines else None
        pytest.fail(f"the child ended with {done.returncode} in the case {last}: "
                    f"{done.stderr[-1500:]}")
    wrong = _judge(CASES3, [r for r in lines if "case" in r])
    assert wrong == [], "\n".join(wrong)


def _with_asan(fmu: Path, out: Path) -> Path:
    """``fmu`` with its binary rebuilt from its own sources under AddressSanitizer and
    UndefinedBehaviorSanitizer (its README's command, the sanitizers added)."""
    import shutil
    import zipfile

    import fmpy

    unzipped = out / "unzipped"
    with zipfile.ZipFile(fmu) as z:
        z.extractall(unzipped)
    (binary,) = unzipped.glob("binaries/*/*.so")
    src = unzipped / "sources"
    subprocess.run(["gcc", "-std=c99", "-O1", "-g", "-fPIC", "-shared",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    "-fno-omit-frame-pointer", f"-I{Path(fmpy.__file__).parent / 'c-code'}",
                    *(str(p) for p in sorted(src.glob("*.c"))), "-o", str(binary), "-lm"],
                   check=True, capture_output=True, timeout=1800)
    path = out / fmu.name
    shutil.make_archive(str(path.with_suffix("")), "zip", unzipped)
    path.with_suffix(".zip").rename(path)
    return path


@pytest.mark.slow
@pytest.mark.needs_cc
@pytest.mark.parametrize("version", ["2", "3"])
def test_the_tables_under_asan(fmu_both: Path, fmu3_both: Path, tmp_path: Path,
                               version: str) -> None:
    """Both tables again with the FMU's C under ASan/UBSan (libasan preloaded into the
    child): no sanitizer report, the same answers."""
    import os

    fmu = _with_asan(fmu_both if version == "2" else fmu3_both, tmp_path)
    asan = subprocess.run(["gcc", "-print-file-name=libasan.so"], capture_output=True,
                          text=True, check=True).stdout.strip()
    env = {**os.environ, "LD_PRELOAD": asan, "ASAN_OPTIONS": "detect_leaks=0"}
    driver, cases = (_DRIVER, CASES) if version == "2" else (_DRIVER3, CASES3)
    done = subprocess.run([sys.executable, "-c", driver, str(fmu),
                           json.dumps([c[:3] for c in cases])], capture_output=True,
                          text=True, timeout=1800, env=env)
    assert "AddressSanitizer" not in done.stderr and "runtime error" not in done.stderr, \
        done.stderr[-3000:]
    assert done.returncode == 0, done.stderr[-3000:]
    results = [json.loads(line) for line in done.stdout.splitlines()
               if line.startswith("{") and '"case"' in line]
    assert _judge(cases, results) == []
