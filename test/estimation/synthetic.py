"""A small truth generator for the estimator's unit tests (not the product simulator).

One interstation run of the motion model dv/dt = u - r(v) - g(s) with known Davis coefficients,
integrated with classical RK4 at 0.1 s (local error ~1e-9 m/s), driven by a scripted driver:
full traction (tractive envelope) to the cruise speed, cruise (u = r + g), coast (u = 0) down to a
braking speed or a braking point, constant-deceleration braking per speed step, stop. Sampled every
``period`` s with Gaussian position noise and speed noise quantised to 1 km/h.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from repo_paths import DATA

from train_calib.estimation import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN
from train_calib.measurement import MeasurementSeries
from train_calib.physics import KMH
from train_calib.train import Davis, TrainSpec, load_train


def virm_like_train(**changes) -> TrainSpec:
    """The VIRM-like train of test/data/small_train.yaml without tunnel factor and adhesion limit."""
    defaults = {"tunnel_factor": 0.0, "adhesive_mass_fraction": 0.0, "source": ""}
    return replace(load_train(DATA / "small_train.yaml"), **{**defaults, **changes})


@dataclass
class Script:
    cruise_speed: float = 130 * KMH  # m/s
    cruise_time: float = 300.0  # s
    coast_until_speed: float = 80 * KMH  # m/s: start braking at this speed ...
    brake_at_s: float = 1e12  # ... or at this position, whichever first
    brake_rates: tuple[float, ...] = (0.35, 0.45, 0.55)  # m/s^2 above 80, 40-80, below 40 km/h
    traction_fraction: float = 1.0  # of the envelope
    gradient_permille: tuple[tuple[float, float], ...] = ((0.0, 0.0), (6000.0, 2.0), (14000.0, -1.5), (22000.0, 0.0))
    recoast: tuple[float, float] = (0.0, 0.0)  # (speed drop before re-traction during cruise, 0 = hold)


@dataclass
class Truth:
    t: np.ndarray
    s: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u: np.ndarray
    g: np.ndarray
    regime: np.ndarray
    resistance: Davis
    dense: dict = field(default_factory=dict)


def gradient_force(script: Script, s: np.ndarray | float) -> np.ndarray:
    starts = np.array([p[0] for p in script.gradient_permille])
    values = np.array([p[1] for p in script.gradient_permille]) * 1e-3 * 9.81
    idx = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(starts) - 1)
    return values[idx]


def integrate(train: TrainSpec, resistance: Davis, script: Script, h: float = 0.1) -> dict:
    """Dense truth at step h: t, s, v, a, u, g, regime."""
    r0, r1, r2 = resistance.as_tuple()

    def res(v):
        return r0 + r1 * v + r2 * v * v

    import bisect

    g_starts = [p[0] for p in script.gradient_permille]
    g_values = [p[1] * 1e-3 * 9.81 for p in script.gradient_permille]

    def g_of(s):
        return g_values[max(bisect.bisect_right(g_starts, s) - 1, 0)]

    edges = np.array([0.0, 40 * KMH, 80 * KMH])
    phase = TRACTION
    t = s = v = 0.0
    cruise_start = None
    out = {k: [] for k in ("t", "s", "v", "a", "u", "g", "regime")}

    def effort(phase, s, v):
        if phase == TRACTION:
            return script.traction_fraction * min(train.max_tractive_effort, train.max_tractive_power / max(v, 0.01))
        if phase == CRUISING:
            return res(v) + g_of(s)
        if phase == COASTING:
            return 0.0
        if phase == BRAKING:
            rate = script.brake_rates[2 - max(int(np.searchsorted(edges, v, side="right")) - 1, 0)]
            return -rate + res(v) + g_of(s)
        return 0.0

    def accel(phase, s, v):
        if phase == UNKNOWN:
            return 0.0
        return effort(phase, s, v) - res(v) - g_of(s)

    while True:
        # phase transitions
        if phase == TRACTION and v >= script.cruise_speed:
            phase, cruise_start = CRUISING, t
        elif phase == CRUISING and t - cruise_start >= script.cruise_time:
            phase = COASTING
        elif phase == COASTING and (v <= script.coast_until_speed or s >= script.brake_at_s):
            phase = BRAKING
        elif phase == BRAKING and v <= 0.0:
            phase, v = UNKNOWN, 0.0
        u = effort(phase, s, v)
        a = accel(phase, s, v)
        for key, val in zip(out, (t, s, v, a, u, g_of(s), phase)):
            out[key].append(val)
        if phase == UNKNOWN:
            break
        # RK4 on (s, v) with the phase held
        k1s, k1v = v, accel(phase, s, v)
        k2s, k2v = v + 0.5 * h * k1v, accel(phase, s + 0.5 * h * k1s, v + 0.5 * h * k1v)
        k3s, k3v = v + 0.5 * h * k2v, accel(phase, s + 0.5 * h * k2s, v + 0.5 * h * k2v)
        k4s, k4v = v + h * k3v, accel(phase, s + h * k3s, v + h * k3v)
        s += h / 6 * (k1s + 2 * k2s + 2 * k3s + k4s)
        v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        t += h
        if phase == BRAKING and v < 0.0:
            v = 0.0
    return {k: np.array(val) for k, val in out.items()}


def sample(
    dense: dict,
    period: float,
    rng: np.random.Generator,
    resistance: Davis,
    pos_std: float = 4.0,
    speed_noise_std: float = 0.1,
    quantum: float = KMH,
    t_end_pad: float = 30.0,
) -> tuple[Truth, MeasurementSeries]:
    """Samples of the dense truth every ``period`` s (standing still for t_end_pad s after the stop)."""
    t_end = dense["t"][-1] + t_end_pad
    times = np.arange(0.0, t_end + 1e-9, period)
    idx = np.minimum(np.searchsorted(dense["t"], times - 1e-9), len(dense["t"]) - 1)
    # interpolate s, v linearly between dense steps (h is small)
    s = np.interp(times, dense["t"], dense["s"])
    v = np.interp(times, dense["t"], dense["v"])
    truth = Truth(
        t=times,
        s=s,
        v=v,
        a=dense["a"][idx],
        u=dense["u"][idx],
        g=dense["g"][idx],
        regime=dense["regime"][idx].astype(np.uint8),
        resistance=resistance,
        dense=dense,
    )
    n = times.size
    s_meas = s + rng.normal(0.0, pos_std, n)
    v_noisy = np.maximum(v + rng.normal(0.0, speed_noise_std, n), 0.0)
    v_meas = np.round(v_noisy / quantum) * quantum if quantum > 0 else v_noisy
    stamps = np.round(times * 1e9).astype(np.int64)
    series = MeasurementSeries(
        stamp_ns=stamps,
        s=s_meas,
        v=v_meas,
        track_force=dense["g"][idx],
        dt=np.concatenate(([0.0], np.diff(times))),
        run_id=np.zeros(n, dtype=np.int64),
        s_measured=np.ones(n, dtype=bool),
        s_variance=np.full(n, pos_std**2),
        v_variance=np.full(n, quantum**2 / 12 + speed_noise_std**2),
        cross_track=np.zeros(n),
        speed_limit=np.full(n, 140 * KMH),
        tunnel_fraction=np.zeros(n),
        power_valid=np.zeros(n, dtype=bool),
        power_consumed=np.zeros(n),
        power_regenerated=np.zeros(n),
    )
    return truth, series


def add_power(series: MeasurementSeries, truth: Truth, train: TrainSpec, rng, rel_noise: float = 0.01) -> None:
    """Pantograph power of the truth effort (traction only): P = f_t v gamma m / eta, 1 % noise."""
    mass = train.effective_mass_kg
    ft = np.maximum(truth.u, 0.0)
    p = ft * truth.v * mass / train.transmission_efficiency
    p = p * (1.0 + rel_noise * rng.standard_normal(p.size))
    series.power_valid[:] = True
    series.power_consumed[:] = np.maximum(p, 0.0)
    series.power_regenerated[:] = 0.0


def make_run(
    seed: int = 0,
    period: float = 10.0,
    resistance: Davis | None = None,
    script: Script | None = None,
    train: TrainSpec | None = None,
    **sample_kw,
) -> tuple[TrainSpec, Truth, MeasurementSeries]:
    train = train or virm_like_train()
    resistance = resistance or train.davis
    script = script or Script()
    dense = integrate(train, resistance, script)
    truth, series = sample(dense, period, np.random.default_rng(seed), resistance, **sample_kw)
    return train, truth, series
