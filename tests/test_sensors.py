"""The sensors: [sensors] validated, the measurement equations (derive/sensors.py) and their
Jacobians, as derived and as generated, against readings computed from the geometry by a
separate numpy routine (tests/independent_reference.py: a ray meeting the track plane, the
accelerometer's point acceleration through a difference of the rotation) and its central
differences."""

from __future__ import annotations

import independent_reference as ref
import numpy as np
import pytest
import sympy as sp

from maglevgen.control.estimation import SensorLayout
from maglevgen.derive.sensors import GapSensorSymbols, measurement_model
from maglevgen.errors import InputError
from maglevgen.params import load_params


def _states(rng: np.random.Generator, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """States near flight (mm, tens of mrad, 20 m/s) and arbitrary rates."""
    scale = np.array([1.0, 2e-3, 2e-3, 0.05, 0.05, 0.05, 2.0, 0.2, 0.2, 1.0, 1.0, 1.0])
    out = []
    for _ in range(n):
        x = rng.normal(size=12) * scale
        x[6] += 20.0
        out.append((x, rng.normal(size=12) * 5.0))
    return out


def _derived(params):
    """derive/sensors.py's model of the default set, lambdified (h, H_x, H_xdot)."""
    layout = SensorLayout.of(params)
    gaps = [(g.name, GapSensorSymbols(sp.Matrix(g.point), sp.Matrix(g.normal),
                                      sp.Float(g.nominal_gap))) for g in layout.gaps]
    model = measurement_model(gaps, sp.Matrix(layout.imu_point),
                              sp.Float(params.vehicle.gravity), layout.track)
    args = [*model.x, *model.xdot]
    return model, [sp.lambdify(args, e, "numpy") for e in (model.y, model.H_x, model.H_xdot)]


def test_derived_readings_and_jacobians_equal_the_geometry() -> None:
    params = load_params().params
    model, (h, H_x, H_xdot) = _derived(params)
    assert model.names == SensorLayout.of(params).names
    for x, xdot in _states(np.random.default_rng(7), 5):
        args = [*x, *xdot]
        y_ref = ref.sensor_readings(params, x, xdot)
        np.testing.assert_allclose(np.ravel(h(*args)), y_ref, rtol=1e-12, atol=1e-11)
        Hx_ref, Hd_ref = ref.sensor_jacobians_fd(params, x, xdot)
        np.testing.assert_allclose(H_x(*args), Hx_ref, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(H_xdot(*args), Hd_ref, rtol=1e-6, atol=1e-6)


def test_a_gap_reading_is_longer_than_the_perpendicular_gap_when_tilted() -> None:
    """The ray along the turned normal meets the plane past the foot of the perpendicular:
    at a 50 mrad roll the reading exceeds the perpendicular gap by 1/cos - 1 = 1.25e-3."""
    params = load_params().params
    x = np.zeros(12)
    x[3] = 0.05
    _, b, n, g0 = ref.gap_sensor_points(params)[0]
    gap = g0 + n @ ((ref.rotation(*x[3:6]) - np.eye(3)) @ b)
    ratio = ref.sensor_readings(params, x, np.zeros(12))[0] / gap
    normal_turn = n @ ref.rotation(*x[3:6]) @ n
    assert ratio == pytest.approx(1 / normal_turn, rel=1e-12)
    assert 1 / normal_turn - 1 > 1e-4  # the 45-degree face turns with the roll


def test_generated_readings_and_jacobians_equal_the_geometry(sim_lib, carriage) -> None:
    """maglev_gap_reading and maglev_imu_reading in the compiled C, sensor by sensor."""
    params = carriage.params
    layout = SensorLayout.of(params)
    gap_fn, imu_fn = sim_lib.function("maglev_gap_reading"), sim_lib.function("maglev_imu_reading")
    for x, xdot in _states(np.random.default_rng(11), 3):
        y, Hx, Hd = [], [], []
        for g in layout.gaps:
            reading, H = gap_fn(x, g.point, g.normal, g.nominal_gap)
            y.append(float(np.ravel(reading)[0]))
            Hx.append(np.ravel(H))
            Hd.append(np.zeros(12))
        gyro, accel, H_x, H_xdot = imu_fn(x, xdot, layout.imu_point, carriage.p)
        y += [*np.ravel(gyro), *np.ravel(accel), x[0]]
        Hx += [*H_x, np.eye(12)[0]]
        Hd += [*H_xdot, np.zeros(12)]
        np.testing.assert_allclose(y, ref.sensor_readings(params, x, xdot), rtol=1e-12,
                                   atol=1e-11)
        Hx_ref, Hd_ref = ref.sensor_jacobians_fd(params, x, xdot)
        np.testing.assert_allclose(np.array(Hx), Hx_ref, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(np.array(Hd), Hd_ref, rtol=1e-6, atol=1e-6)


def test_default_sensor_noise_at_the_tick() -> None:
    """Each reading's variance: RMS^2 + step^2/12, a density N through a first-order filter
    at f_c: N^2 (pi/2) f_c (written out here from the defaults file's numbers)."""
    layout = SensorLayout.of(load_params().params)
    var = dict(zip(layout.names, layout.variances, strict=True))
    assert var["gap_g3l"] == pytest.approx(10e-6**2 + 1e-6**2 / 12, rel=1e-12)
    assert var["gyro_q"] == pytest.approx(1.75e-4**2 * np.pi / 2 * 400.0, rel=1e-12)
    assert var["accel_z"] == pytest.approx(1e-3**2 * np.pi / 2 * 400.0, rel=1e-12)
    assert var["track_x"] == pytest.approx(1e-3**2 / 12, rel=1e-12)


@pytest.mark.parametrize(("override", "key", "why"), [
    ('sensors.gap_sensors.g1.array="9"', "sensors.gap_sensors.g1.array", "not an array"),
    ("sensors.gap_sensors.g3l.across=0.07", "sensors.gap_sensors.g3l.across", "off the face"),
    ("sensors.gap_sensors.g3l.along=0.2", "sensors.gap_sensors.g3l.along", "off the face"),
    ("sensors.imu.anti_alias=600.0", "sensors.imu.anti_alias", "Nyquist"),
    ("sensors.track.sample_rate=100.0", "sensors.track.sample_rate", "tick_rate"),
    ("sensors.gap.noise=-1e-6", "sensors.gap.noise", "outside the range"),
])
def test_bad_sensors_name_the_key(override: str, key: str, why: str) -> None:
    with pytest.raises(InputError) as exc:
        load_params(overrides=[override])
    msg = str(exc.value)
    assert "\n" not in msg and f"{key} = " in msg and why in msg, msg
