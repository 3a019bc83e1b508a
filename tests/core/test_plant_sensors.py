"""ambid.plant.sensors: the sensor model the simulator runs, against closed forms written here."""

import numpy as np
import pytest
from scipy import stats

from ambid.plant.rig import make_rig
from ambid.plant.sensors import Sensors
from ambid.plant.simulator import PlantSimulator
from ambid.plant.true_rig import true_plant


def test_true_plant_sensor_path_is_the_closed_form_low_pass():
    """r_s -> y of the true rig is gain wc / (s + wc) per channel and nothing across channels."""
    rig = make_rig({"sensor_bandwidth_hz": 3_000.0, "sensor_gain": 1.25})
    p = true_plant(rig)
    wc = 2 * np.pi * 3_000.0
    for f in (10.0, 900.0, 3_000.0, 12_000.0):
        s = 2j * np.pi * f
        g = p.c_y @ np.linalg.solve(s * np.eye(p.a.shape[0]) - p.a, p.b_s)
        expected = 1.25 * wc / (s + wc)
        assert np.allclose(g, expected * np.eye(4), rtol=1e-9, atol=1e-12)
        assert np.allclose(np.diag(g), Sensors.from_rig(rig.values).frequency_response(f), rtol=1e-9)


def test_simulator_reading_at_rest_is_the_static_curve():
    c3, gain = 8e5, 0.9
    rig = make_rig({"sensor_cubic_per_m2": c3, "sensor_noise_m": 0.0, "sensor_gain": gain})
    sim = PlantSimulator(rig)
    d = sim.plant.c_sensor @ sim.x
    assert np.allclose(sim.output(), gain * (d + c3 * d ** 3), rtol=1e-9)
    assert np.allclose(sim.output(), [x.static_curve(dj) for x, dj in zip(sim.sensors, d)], rtol=1e-9)


def test_simulator_noise_has_the_rigs_std_and_is_white_and_seeded():
    std = 1.5e-6
    rig = make_rig({"sensor_noise_m": std})
    n = 6000
    runs = []
    for seed in (3, 3, 4):
        sim = PlantSimulator(rig, seed=seed)
        y = np.empty((n, 4))
        for k in range(n):  # at rest on the backup bearings with zero current: only the noise moves
            y[k] = sim.output()
            sim.step(np.zeros(4))
        runs.append(y)
    assert np.array_equal(runs[0], runs[1])
    assert not np.allclose(runs[0], runs[2])
    e = runs[0] - runs[0].mean(axis=0)
    # sample variance of n - 1 degrees of freedom: a 99.9 % chi-square interval per channel
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n - 1) / (n - 1)
    var = e.var(axis=0, ddof=1) / std ** 2
    assert np.all((var > lo) & (var < hi)), var
    # white: lag-1 autocorrelation within 4 standard errors of zero, channels uncorrelated
    r1 = np.sum(e[1:] * e[:-1], axis=0) / np.sum(e * e, axis=0)
    assert np.all(np.abs(r1) < 4 / np.sqrt(n))
    c = np.corrcoef(e.T)
    assert np.all(np.abs(c[~np.eye(4, dtype=bool)]) < 4 / np.sqrt(n))


@pytest.mark.parametrize("bad", [{"sensor_bandwidth_hz": 0.0}, {"sensor_gain": 0.0}, {"sensor_noise_m": -1.0}])
def test_rig_refuses_impossible_sensors(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        make_rig(bad)
