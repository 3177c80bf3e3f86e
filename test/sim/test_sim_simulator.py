"""The realistic driver simulation: physics, stops, limits, labels, determinism, the truth's consistency."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from sim_helpers import track, train

from train_calib.errors import ConfigError
from train_calib.sim import (
    BRAKING,
    COASTING,
    CRUISING,
    TRACTION,
    UNKNOWN,
    DriverParams,
    SensorParams,
    simulate_run,
)
from train_calib.train import Davis

CASES = [
    ("intercity_32km", "virm6"),
    ("intercity_32km", "virm10"),
    ("tunnel_line_37km", "icrm"),
    ("dense_corridor_14km", "virm4"),
]


def _runs():
    out = []
    for k, (track_name, train_name) in enumerate(CASES):
        for style in ("hold", "cycles"):
            rng = np.random.default_rng([7, k, len(style)])
            trn = train(train_name)
            driver = DriverParams.sample(
                rng,
                train=trn,
                styles=(style,),
                wind=True,
                coast_range_s=(100.0, 400.0) if "dense" in track_name else (150.0, 600.0),
            )
            run = simulate_run(track(track_name), trn, driver=driver, sensors=SensorParams(), rng=rng)
            out.append((track_name, train_name, driver, run))
    return out


@pytest.fixture(scope="module")
def runs():
    return _runs()


def test_every_run_stops_at_the_station_within_1_m(runs):
    for track_name, _, _driver, run in runs:
        summary = run.meta["summary"]
        assert abs(summary["stop_error_m"]) < 1.0
        assert run.dense.s[-1] == pytest.approx(run.meta["stop_s"], abs=1.0)
        assert run.dense.v[-1] == 0.0
        assert summary["distance_m"] == pytest.approx(run.meta["stop_s"] - run.meta["start_s"])
        assert np.all(np.diff(run.dense.s) >= -1e-9), track_name  # never rolls back


def test_speed_never_exceeds_the_drivers_theta_times_the_limit(runs):
    for track_name, train_name, driver, run in runs:
        d = run.dense
        trk, trn = track(track_name), train(train_name)
        limit = np.array([trk.limit_over_train(float(s), trn.length_m) for s in d.s])
        allowed = max(driver.theta_cruise, 1.0) * limit
        assert np.all(d.v <= allowed + 1e-6), (track_name, driver.cruise_style, float(np.max(d.v - allowed)))


def test_regime_labels_match_effort_and_acceleration(runs):
    for _, _, _, run in runs:
        d = run.dense
        traction, cruising = d.regime == TRACTION, d.regime == CRUISING
        coasting, braking, standing = d.regime == COASTING, d.regime == BRAKING, d.regime == UNKNOWN
        assert np.all(d.u[traction] >= 0.0)
        assert np.all(d.a[cruising] == 0.0)
        assert np.all(d.u[coasting] == 0.0)
        assert np.all(d.u[braking] < 0.0)
        assert np.all(d.v[standing] == 0.0)
        assert traction.any() and coasting.any() and braking.any()
        # the effort identity u = a + r(v) + g(s) on the moving samples
        moving = d.v > 0
        r = d.r0 + d.r1 * d.v + d.r2 * (1 + run.meta["train"]["tunnel_factor"] * d.tunnel_fraction) * d.v**2
        assert np.allclose(d.u[moving], (d.a + r + d.track_force)[moving], atol=1e-12)


def test_dense_trajectory_is_consistent_with_its_acceleration(runs):
    """Between consecutive dense samples of one smooth phase, the truth acceleration integrates to the
    truth speed change and the speed to the distance (the stored steps are the ODE's solution)."""
    for _, _, _, run in runs:
        d = run.dense
        dt = np.diff(d.t)
        smooth = (d.regime[1:] == d.regime[:-1]) & (np.abs(np.diff(d.a)) < 0.02) & (d.v[:-1] > 0)
        dv_trap = 0.5 * (d.a[1:] + d.a[:-1]) * dt
        # trapezoid over 0.5 s: errors come from kinks of a inside an interval (measured < 2.1e-3 m/s);
        # a wrong stored acceleration (sign, factor) would be off by ~a * dt ~ 0.1 m/s
        assert np.max(np.abs(np.diff(d.v) - dv_trap)[smooth]) < 5e-3
        ds_trap = 0.5 * (d.v[1:] + d.v[:-1]) * dt
        assert np.max(np.abs(np.diff(d.s) - ds_trap)[smooth]) < 5e-3


def test_coasting_deceleration_equals_resistance_plus_track_force_on_the_flat():
    """Coasting on level, straight, open track: dv/dt = -(r0 + r1 v + r2 v^2), checked on the dense
    trajectory by numerical differentiation (independent of the truth's own a)."""
    trk, trn = track("intercity_32km"), train("virm6")
    driver = DriverParams(theta_cruise=1.0, coast_before_brake_s=500.0, b_limit=(0.5,) * 5, b_stop=0.6)
    true = Davis(0.012, 2.5e-4, 3.5e-5)
    run = simulate_run(
        trk, trn, driver=driver, sensors=SensorParams(), rng=np.random.default_rng(1), resistance=true, dense_dt_s=0.5
    )
    d = run.dense
    t = d.t
    dvdt = np.gradient(d.v, t)
    flat = (d.regime == COASTING) & (d.track_force == 0.0) & (d.tunnel_fraction == 0.0)
    inner = flat & np.roll(flat, 1) & np.roll(flat, -1) & np.roll(flat, 2) & np.roll(flat, -2)
    assert inner.sum() > 300  # > 150 s of open-track coasting
    expected = -(true.r0 + true.r1 * d.v + true.r2 * d.v**2)
    assert np.max(np.abs(dvdt[inner] - expected[inner])) < 1e-6  # m/s^2; central differences over 0.5 s: 4e-8
    assert np.allclose(d.a[flat], expected[flat], rtol=0, atol=1e-15)
    # the realised final coast is the planned one (no wind, hold style)
    assert run.meta["summary"]["final_coast_s"] == pytest.approx(500.0, abs=5.0)


def test_gentle_start_and_wind_in_the_truth():
    trk, trn = track("intercity_32km"), train("virm6")
    driver = DriverParams(
        start_ramp_s=15.0, traction_fraction=0.8, wind_r2=0.1, wind_amplitude=0.05, wind_period_s=600.0
    )
    run = simulate_run(trk, trn, driver=driver, sensors=SensorParams(pre_roll_s=10.0), rng=np.random.default_rng(2))
    d = run.dense
    t = (d.t_ns - run.meta["departure_time_ns"]) * 1e-9
    ramp = (t > 0) & (t < 15.0)
    # traction grows linearly from 0 to 0.8 c0 over 15 s; the train stands until it beats r0 + g
    assert np.allclose(d.u[ramp], 0.8 * trn.max_tractive_effort * t[ramp] / 15.0, rtol=1e-9)
    assert np.all(d.v[t <= 0.0] == 0.0)
    assert d.r2.min() == pytest.approx(trn.davis.r2 * 1.05, rel=1e-3)
    assert d.r2.max() == pytest.approx(trn.davis.r2 * 1.15, rel=1e-3)


def test_same_seed_same_run_and_stations_by_name():
    trk, trn = track("dense_corridor_14km"), train("virm4")

    def make(seed):
        rng = np.random.default_rng(seed)
        driver = DriverParams.sample(rng, train=trn, coast_range_s=(60.0, 200.0))
        return simulate_run(
            trk,
            trn,
            driver=driver,
            sensors=SensorParams(),
            rng=rng,
            start_station="Rotterdam Centraal",
            stop_station="Delft",
        )

    a, b, c = make(5), make(5), make(6)
    assert np.array_equal(a.truth.s, b.truth.s) and np.array_equal(a.gnss.lat, b.gnss.lat)
    assert not np.array_equal(a.truth.s, c.truth.s)
    with pytest.raises(ConfigError, match="no station named 'Utrecht'"):
        simulate_run(
            trk,
            trn,
            driver=DriverParams(),
            sensors=SensorParams(),
            rng=np.random.default_rng(0),
            stop_station="Utrecht",
        )
    with pytest.raises(ConfigError, match="must lie beyond"):
        simulate_run(
            trk,
            trn,
            driver=DriverParams(),
            sensors=SensorParams(),
            rng=np.random.default_rng(0),
            start_station="Delft",
            stop_station="Rotterdam Centraal",
        )


def test_driver_sampling_follows_the_papers():
    rng = np.random.default_rng(11)
    trn = train("virm6")
    drivers = [DriverParams.sample(rng, train=trn) for _ in range(400)]
    theta = np.array([d.theta_cruise for d in drivers])
    assert theta.min() >= 0.8 and theta.max() <= 1.02
    assert 0.07 < np.mean(theta > 1.0) < 0.17  # Cunillera: 12 % of the runs above the limit
    coast = np.array([d.coast_before_brake_s for d in drivers])
    assert coast.min() >= 150.0 and coast.max() <= 600.0
    b = np.array([d.b_limit for d in drivers])
    assert b.min() >= 0.24 and b.max() <= trn.max_brake_decel
    assert np.mean(b[:, 4] >= b[:, 0] - 0.06) > 0.95  # braking harder at low speed
    assert {d.cruise_style for d in drivers} == {"hold", "cycles"}
    band = np.array([d.cycle_band_kmh for d in drivers])
    assert band.min() >= 6.0 and band.max() <= 15.0  # coasting 20-50 s at 140 km/h, longer lower
    assert min(d.cycle_traction_fraction for d in drivers) >= 0.8
    with pytest.raises(ConfigError, match=r"^x.yaml: driver.b_limit: needs one value per speed step \(5\), found 2$"):
        DriverParams.from_mapping({"b_limit": [0.5, 0.5]}, "x.yaml", "driver.")
    with pytest.raises(ConfigError, match="DriverParams: b_limit"):
        simulate_run(
            track("intercity_32km"), trn, driver=DriverParams(b_limit=(0.5, 0.5)), sensors=SensorParams(), rng=rng
        )
    with pytest.raises(ConfigError, match="cruise_style"):
        DriverParams().replace(cruise_style="sport")


@pytest.mark.parametrize("seed", range(6))
def test_a_fleet_of_random_drivers(seed):
    """Random drivers (styles, wind, brake steps, coasting) on every track: no failure, exact stops, no overspeed."""
    for k, (track_name, train_name) in enumerate(
        [
            ("intercity_32km", "virm4"),
            ("tunnel_line_37km", "virm10"),
            ("dense_corridor_14km", "icrm"),
            ("dense_corridor_14km", "virm6"),
        ]
    ):
        trk, trn = track(track_name), train(train_name)
        rng = np.random.default_rng([31, seed, k])
        scale = min(1.0, (trk.stations[-1].s_m - trk.stations[0].s_m) / 32103.0)
        driver = DriverParams.sample(rng, train=trn, wind=seed % 2 == 1, coast_range_s=(150 * scale, 600 * scale))
        run = simulate_run(trk, trn, driver=driver, sensors=SensorParams(pre_roll_s=0.0), rng=rng, dense_dt_s=1.0)
        d = run.dense
        limit = np.array([trk.limit_over_train(float(s), trn.length_m) for s in d.s])
        assert np.all(d.v <= max(driver.theta_cruise, 1.0) * limit + 1e-6), (track_name, driver)
        assert abs(run.meta["summary"]["stop_error_m"]) < 1e-3
        assert np.all(np.diff(d.s) >= -1e-9)


def test_traction_coast_cycles_are_realistic(runs):
    """Cycles (Cunillera Fig. 3: brief re-accelerations, coasting while above the target): every cycle coasts for
    tens of seconds from the target down by the band, and its re-acceleration really accelerates (at least
    cycle_min_accel net where it starts, up to the full envelope) back to the target."""
    checked = 0
    for _track, _train, driver, run in runs:
        if driver.cruise_style != "cycles":
            continue
        d, t0 = run.dense, run.meta["start_time_ns"]
        t = (d.t_ns - t0) * 1e-9
        events = run.meta["summary"]["driver_events"]
        for (ta, ea), (tb, eb) in itertools.pairwise(events):
            if ea == "traction:target" and eb == "coast:band_low":  # a whole cycle coast
                seg = (t >= ta) & (t <= tb)
                assert tb - ta > 15.0, (ta, tb)
                drop = d.v[seg][0] - d.v[seg][-1]
                assert drop == pytest.approx(driver.cycle_band_kmh / 3.6, abs=0.1)  # 0.5 s grid
                checked += 1
            if ea == "coast:band_low":  # the re-acceleration: ramp, then traction up to the next event
                tend = next((te for te, _e in events if te > ta + driver.reaccel_ramp_s + 1e-6), ta)
                seg = (t > ta + driver.reaccel_ramp_s) & (t < tend) & (d.regime == TRACTION)
                if seg.sum() > 4:  # after the ramp: accelerating (uphill 6 per mille at 143 km/h: 0.013 m/s^2)
                    assert np.min(d.a[seg]) > 0.0 and np.mean(d.a[seg]) > 0.03
    assert checked >= 10


def test_final_phase_truth_is_the_last_coast_and_the_last_brake(runs):
    """The truth JSON's final_coast_s / final_brake_s, checked on the dense labels: the last braking phase is the one
    that ends at the stop, the final coast the last coasting phase before it (also where the run ends
    brake -> hold at a lower limit -> stop brake)."""
    for _track, _train, _driver, run in runs:
        d, summary = run.dense, run.meta["summary"]
        t = (d.t_ns - d.t_ns[0]) * 1e-9
        moving = d.v > 0.0
        cuts = np.flatnonzero(np.diff(d.regime.astype(int)) != 0) + 1
        phases = [(int(d.regime[a]), t[a], t[b - 1]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, t.size])]
        brakes = [p for p in phases if p[0] == BRAKING]
        coasts = [p for p in phases if p[0] == COASTING and p[2] <= brakes[-1][1] + 0.5]
        arrival = t[moving][-1]
        assert brakes[-1][2] == pytest.approx(arrival, abs=0.6)
        dense_dt = run.meta["dense_dt_s"]
        assert summary["final_brake_s"] == pytest.approx(brakes[-1][2] - brakes[-1][1], abs=2 * dense_dt)
        assert summary["final_coast_s"] == pytest.approx(coasts[-1][2] - coasts[-1][1], abs=2 * dense_dt)
