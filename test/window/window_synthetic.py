"""Synthetic 1 Hz runs with pantograph power for the window tests, independent of train_calib.sim.

``euler_run`` integrates the discrete model of De Martinis eq. 4 exactly (v_k+1 = v_k + dt a_k), so
the forward-difference fit must recover the resistance exactly on noise-free data; ``fine_run``
integrates the continuous model (RK4, 0.1 s steps) and samples it at 1 Hz (the physical case).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from repo_paths import DATA

from train_calib import physics
from train_calib.measurement import MeasurementSeries
from train_calib.train import Davis, TrainSpec, load_train

TRUTH = Davis(r0=0.0085, r1=1.5e-4, r2=5.2e-5)  # N/kg: differs from the train file's manufacturer values

# (phase, target speed m/s or duration s): traction to a speed, cruise / coast for a time, brake to a speed
PLAN = (
    ("traction", 25.0),
    ("cruise", 40.0),
    ("traction", 38.0),
    ("cruise", 60.0),
    ("coast", 70.0),
    ("traction", 33.0),
    ("brake", 12.0),
    ("traction", 30.0),
    ("coast", 40.0),
    ("brake", 3.0),
)
REGIME = {"traction": 1, "cruise": 2, "coast": 3, "brake": 4}


def train_spec(**changes) -> TrainSpec:
    """The VIRM-like train of test/data/small_train.yaml (tunnel factor 0.6, adhesion limit on half the mass)."""
    return replace(load_train(DATA / "small_train.yaml"), **{"name": "synthetic-emu", "source": "", **changes})


def gradient_permille(s):
    """A rolling profile: +-6 per mille blocks of 1.5 km."""
    return np.where((np.asarray(s) // 1500) % 3 == 0, 6.0, np.where((np.asarray(s) // 1500) % 3 == 1, -4.0, 0.0))


def tunnel(s):
    s = np.asarray(s)
    return (((s > 3000) & (s < 4200)) | ((s > 9000) & (s < 10500))).astype(float)


@dataclass
class SyntheticRun:
    series: MeasurementSeries
    v_true: np.ndarray
    regime: np.ndarray  # DrivingRegime of each sample's step
    truth: Davis


def _effort(phase, target, v, r_plus_g, env):
    if phase == "traction":
        return env
    if phase == "cruise":
        return float(np.clip(r_plus_g, -0.4, env))
    if phase == "coast":
        return 0.0
    return -0.45


def _plan_step(state, t, v):
    """Advance the plan; returns (phase, target)."""
    while True:
        phase, target = PLAN[state["i"]]
        if (
            (phase == "traction" and v >= target)
            or (phase in ("cruise", "coast") and t - state["t0"] >= target)
            or (phase == "brake" and v <= target)
        ):
            state["i"] += 1
            state["t0"] = t
        else:
            return phase, target
        if state["i"] >= len(PLAN):
            return None, None


def _simulate(train, truth, dt_sample, substeps, electric_brake_max, t_max=2000.0):
    h = dt_sample / substeps
    mass = train.effective_mass_kg
    state = {"i": 0, "t0": 0.0}
    t, s, v = 0.0, 0.0, 0.5
    out = []
    phase, target = _plan_step(state, t, v)
    while phase is not None and t < t_max:
        g = physics.GRAVITY * gradient_permille(s) / 1000.0
        tau = float(tunnel(s))
        r = truth(v, tau, train.tunnel_factor)
        env = float(train.tractive_envelope(v))
        u = _effort(phase, target, v, r + g, env)
        electric = max(u, -electric_brake_max)
        wheel_power = electric * mass * v
        consumed = wheel_power / train.transmission_efficiency if wheel_power > 0 else 0.0
        regenerated = -wheel_power * train.transmission_efficiency if wheel_power < 0 else 0.0
        out.append((t, s, v, g, tau, consumed + train.auxiliary_power_kw * 1000.0, regenerated, REGIME[phase]))
        if substeps == 1:  # the discrete model itself
            a = u - r - g
            s, v = s + h * v, max(v + h * a, 0.0)
        else:  # RK4 on (s, v) with the effort held over the sample period (zero-order hold)
            for _ in range(substeps):
                s, v = _rk4(train, truth, u, s, v, h)
        t += dt_sample
        phase, target = _plan_step(state, t, v)
    return np.array(out)


def _rk4(train, truth, u, s, v, h):
    def f(s_, v_):
        g_ = physics.GRAVITY * gradient_permille(s_) / 1000.0
        return v_, u - truth(v_, float(tunnel(s_)), train.tunnel_factor) - g_

    k1 = f(s, v)
    k2 = f(s + 0.5 * h * k1[0], v + 0.5 * h * k1[1])
    k3 = f(s + 0.5 * h * k2[0], v + 0.5 * h * k2[1])
    k4 = f(s + h * k3[0], v + h * k3[1])
    s_new = s + h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
    v_new = v + h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return s_new, max(float(v_new), 0.0)


def _series(data, train, rng, speed_noise, power_noise) -> tuple[MeasurementSeries, np.ndarray]:
    n = len(data)
    v_true = data[:, 2]
    v = v_true + (rng.normal(0.0, speed_noise, n) if speed_noise > 0 else 0.0)
    v = np.maximum(v, 0.0)
    consumed, regenerated = data[:, 5].copy(), data[:, 6].copy()
    if power_noise > 0:
        consumed = np.where(consumed > 0, consumed * (1 + rng.normal(0, power_noise, n)), consumed)
        regenerated = np.where(regenerated > 0, regenerated * (1 + rng.normal(0, power_noise, n)), regenerated)
    series = MeasurementSeries(
        stamp_ns=(1_700_000_000_000_000_000 + np.rint(data[:, 0] * 1e9)).astype(np.int64),
        s=data[:, 1],
        v=v,
        track_force=data[:, 3],
        dt=np.concatenate(([0.0], np.diff(data[:, 0]))),
        run_id=np.zeros(n, dtype=np.int64),
        s_measured=np.ones(n, dtype=bool),
        s_variance=np.full(n, 16.0),
        v_variance=np.full(n, max(speed_noise, 0.0) ** 2),
        cross_track=np.zeros(n),
        speed_limit=np.full(n, 44.0),
        tunnel_fraction=data[:, 4],
        power_valid=np.ones(n, dtype=bool),
        power_consumed=consumed,
        power_regenerated=regenerated,
    )
    return series, v_true


def euler_run(train=None, truth=TRUTH, rng=0, speed_noise=0.0, power_noise=0.0, electric_brake_max=1.0):
    """Discrete model with 1 s Euler steps: the forward-difference eq. 4 holds exactly without noise."""
    train = train or train_spec()
    data = _simulate(train, truth, 1.0, 1, electric_brake_max)
    series, v_true = _series(data, train, np.random.default_rng(rng), speed_noise, power_noise)
    return SyntheticRun(series, v_true, data[:, 7].astype(np.uint8), truth)


def fine_run(train=None, truth=TRUTH, rng=0, speed_noise=0.0, power_noise=0.0, electric_brake_max=1.0):
    """Continuous model (RK4, 0.1 s steps, effort held for 1 s) sampled at 1 Hz."""
    train = train or train_spec()
    data = _simulate(train, truth, 1.0, 10, electric_brake_max)
    series, v_true = _series(data, train, np.random.default_rng(rng), speed_noise, power_noise)
    return SyntheticRun(series, v_true, data[:, 7].astype(np.uint8), truth)


FAST_TRAIN = train_spec(adhesive_mass_fraction=0.25, tunnel_factor=0.4, auxiliary_power_kw=150.0)
"""The streaming tests' train: the adhesion limit on a quarter of the mass, tunnels, 150 kW auxiliaries."""


def streaming_runs() -> list[tuple[str, TrainSpec, MeasurementSeries]]:
    """(name, train, series) of the runs the streaming tests compare paths on: an exact and a noisy discrete
    run, a noisy fine run, and a fine run with 1 km/h speeds (long windows of identical speeds: ill posed)."""
    tight = train_spec(adhesive_mass_fraction=0.25)
    quantised = fine_run(train=tight, speed_noise=0.1, power_noise=0.01, rng=4).series
    return [
        ("euler exact", FAST_TRAIN, euler_run(train=FAST_TRAIN, rng=1).series),
        ("euler noisy", FAST_TRAIN, euler_run(train=FAST_TRAIN, speed_noise=0.05, power_noise=0.02, rng=2).series),
        ("fine noisy", tight, fine_run(train=tight, speed_noise=0.05, power_noise=0.02, rng=3).series),
        ("fine quantised", tight, replace(quantised, v=np.round(quantised.v * 3.6) / 3.6)),
    ]
