"""Sensor models (statistics against their parameters) and the core-ready measurements."""

from __future__ import annotations

import numpy as np
import pytest
from sim_helpers import track, train

from train_calib.physics import KMH
from train_calib.sim import DriverParams, SensorParams, simulate_run
from train_calib.sim.sensors import pantograph_power


@pytest.fixture(scope="module")
def run_1hz():
    trk, trn = track("tunnel_line_37km"), train("icrm")
    rng = np.random.default_rng(2019)
    driver = DriverParams.sample(rng, train=trn)
    return simulate_run(trk, trn, driver=driver, sensors=SensorParams.paper_1hz_power(), rng=rng)


def test_gnss_noise_and_tunnel_outage(run_1hz):
    trk = track("tunnel_line_37km")
    g = run_1hz.gnss
    ok = g.status >= 0
    east, north = trk.to_enu(g.lat[ok], g.lon[ok])
    e0, n0 = trk.enu_at(g.s_true[ok])
    de, dn = east - e0, north - n0
    n = ok.sum()
    assert n > 900
    # sample std of N(0, 4^2): standard error 4 / sqrt(2 n) ~ 0.09 m
    assert np.std(de) == pytest.approx(4.0, abs=0.4) and np.std(dn) == pytest.approx(4.0, abs=0.4)
    assert abs(np.mean(de)) < 0.5 and abs(np.mean(dn)) < 0.5
    assert np.allclose(de, g.east_err[ok], atol=1e-6) and np.allclose(dn, g.north_err[ok], atol=1e-6)
    # no fix while the head is in a tunnel; NaN positions there
    in_tunnel = np.zeros(g.s_true.size, dtype=bool)
    for t in trk.tunnels:
        in_tunnel |= (g.s_true >= t.start_m) & (g.s_true <= t.end_m)
    assert in_tunnel.sum() > 50
    assert np.array_equal(g.status < 0, in_tunnel)
    assert np.isnan(g.lat[~ok]).all()


def test_speed_quantisation_and_noise(run_1hz):
    v_meas = run_1hz.speed.v_ms / KMH
    assert np.allclose(v_meas, np.round(v_meas), atol=1e-9)  # whole km/h
    err = (run_1hz.speed.v_ms - run_1hz.truth.v) / KMH
    moving = run_1hz.truth.v > 0
    # noise 0.5 km/h then rounding: std sqrt(0.5^2 + 1/12) = 0.577 km/h
    assert np.std(err[moving]) == pytest.approx(np.sqrt(0.25 + 1 / 12), abs=0.05)
    assert np.all(run_1hz.speed.v_ms[~moving] == 0.0)


def test_streams_are_not_synchronised_and_cover_the_run(run_1hz):
    gnss_t, speed_t = run_1hz.gnss.t_ns, run_1hz.speed.t_ns
    assert np.all(np.diff(speed_t) == 1_000_000_000)
    assert (gnss_t[0] - speed_t[0]) % 1_000_000_000 != 0
    assert speed_t[0] >= run_1hz.meta["start_time_ns"] and speed_t[-1] <= run_1hz.meta["end_time_ns"]
    assert run_1hz.truth.t_ns.tolist() == speed_t.tolist()


def test_power_model(run_1hz):
    trn = train("icrm")
    tr = run_1hz.truth
    eta = trn.transmission_efficiency
    traction = tr.u > 0
    assert np.allclose(tr.power_consumed[traction], tr.u[traction] * tr.v[traction] * trn.effective_mass_kg / eta)
    assert np.all(tr.power_regenerated[traction] == 0.0)
    braking = (tr.u < 0) & (tr.v > 10 * KMH)
    assert np.all(tr.power_regenerated[braking] > 0) and np.all(tr.power_consumed[braking] == 0)
    # the recorded stream: 1 % noise around the truth (same stamps as the speed here)
    sensors = SensorParams.paper_1hz_power(speed_offset_s=0.25, power_offset_s=0.25, gnss_offset_s=0.5)
    run = simulate_run(
        track("tunnel_line_37km"), trn, driver=DriverParams(), sensors=sensors, rng=np.random.default_rng(3)
    )
    p = run.power
    assert p is not None and np.array_equal(p.t_ns, run.truth.t_ns)
    big = run.truth.power_consumed > 1e6
    assert np.std(p.consumed_w[big] / run.truth.power_consumed[big] - 1.0) == pytest.approx(0.01, abs=0.002)
    assert np.all(p.consumed_w[run.truth.power_consumed == 0] == 0)
    # the regenerated power: capped at the rated power, fading out at low speed
    cons, regen = pantograph_power(
        np.array([-0.5, -0.5, 0.2]),
        np.array([30.0, 1.0, 10.0]),
        effective_mass_kg=1e5,
        efficiency=0.8,
        max_power_w=1e6,
        electric_brake_fraction=1.0,
        electric_brake_min_ms=2.0,
        auxiliary_w=0.0,
    )
    assert regen.tolist() == [0.8e6, 0.8 * 0.5 * 1e5 * 1.0 * 0.5, 0.0] and cons[2] == pytest.approx(0.2e6 / 0.8)


def test_measurements_are_core_ready(run_1hz):
    trk, trn = track("tunnel_line_37km"), train("icrm")
    m = run_1hz.measurements(trk, trn)
    tr = run_1hz.truth
    assert len(m) == len(tr) and np.array_equal(m.stamp_ns, tr.t_ns)
    measured = m.s_measured
    err = (m.s - tr.s)[measured]
    # interpolating between fixes averages the noise a little: sigma <= 4 m, and no bias
    assert 2.5 < np.std(err) < 4.4 and abs(np.mean(err)) < 0.5
    # dead-reckoned through the tunnels, within tens of metres
    assert (~measured).sum() > 50 and np.max(np.abs((m.s - tr.s)[~measured])) < 30.0
    assert m.dt[0] == 0.0 and np.allclose(m.dt[1:], 1.0)
    assert np.allclose(m.track_force, trk.track_force(m.s, trn.length_m))
    assert m.power_valid.mean() > 0.99
    assert np.allclose(m.v_variance, (1 / 3.6) ** 2 / 12 + (0.5 / 3.6) ** 2)


def test_gauss_markov_gnss_errors_are_correlated():
    trk, trn = track("intercity_32km"), train("virm6")
    sensors = SensorParams(gnss_period_s=1.0, speed_period_s=1.0, gnss_correlation_s=60.0)
    run = simulate_run(trk, trn, driver=DriverParams(), sensors=sensors, rng=np.random.default_rng(4))
    e = run.gnss.east_err
    lag1 = np.corrcoef(e[:-1], e[1:])[0, 1]
    assert lag1 == pytest.approx(np.exp(-1.0 / 60.0), abs=0.02)
    assert np.std(e) == pytest.approx(4.0, abs=1.0)
