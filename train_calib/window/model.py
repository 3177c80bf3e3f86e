"""Their eq. 3-5: measured tractive force from pantograph power and the difference equation per step.

Everything here is per unit of effective mass M = gamma * m (N/kg), the unit of r0, r1, r2 in
train_calib; multiply by M for the paper's force units (A, B, C in N, N/(m/s), N/(m/s)^2). Per step
k -> k+1 (De Martinis eq. 4, divided by M):

    f_k - (r0 + r1 v_k + r2 v_k^2 (1 + f_tun tau_k)) - g_k = (v_{k+1} - v_k) / dt_k

with f_k the measured tractive force, g_k the track force (gradient + curves over the train length,
N/kg of effective mass as everywhere in train_calib) and tau_k the tunnel fraction. It is linear in
theta = (r0, r1, r2): y_k = x_k . theta + e_k with x_k = (1, v_k, v_k^2 (1 + f_tun tau_k)) and
y_k = f_k - g_k - a_k. The residual e_k times M is their E_k (eq. 8), in N.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .. import physics
from ..regime_codes import BRAKING, COASTING, CRUISING, REGIME_NAMES, TRACTION, UNKNOWN  # noqa: F401 (re-exported)
from ..train import TrainSpec
from .config import DIFFERENCE_SCHEMES, WindowConfig

SAUTHOFF_TEXTBOOK_ABC = (2048.0, 98.4, 6.89)
"""De Martinis eq. 9, the Sauthoff coefficients of their train, read as A [N], B [N/(m/s)], C [N/(m/s)^2].

Printed as "A=2048 [1000*kg*m/s^2]; B=98,4 [1000*kg/s]; C=6,89 [1000*kg/m]". Taken literally (kN)
A would be 2 MN, half the weight of a 400 t train; read in N they give 13 kN at 120 km/h for a
~400 t EMU (r = 0.03 N/kg), the order of a Davis curve. docs/window.md discusses the choice.
"""


def tractive_force(v, power_consumed, power_regenerated, train: TrainSpec, min_speed: float) -> np.ndarray:
    """Measured tractive force at the wheel (their eq. 3), N; NaN where v < min_speed.

    Traction: the wheel gets eta times the pantograph power net of the auxiliary (hotel) load,
    F = eta (P_consumed - P_aux) / v. Electric braking: the pantograph gets eta times the wheel
    power, F = -P_regenerated / (eta v) (negative force). P in W, v in m/s.
    """
    v = np.asarray(v, dtype=float)
    consumed = np.asarray(power_consumed, dtype=float) - train.auxiliary_power_kw * 1000.0
    regenerated = np.asarray(power_regenerated, dtype=float)
    eta = train.transmission_efficiency
    wheel_power = np.where(consumed > 0.0, eta * consumed, 0.0) - regenerated / eta
    wheel_power = np.where(consumed < 0.0, wheel_power + consumed / eta, wheel_power)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(v >= min_speed, wheel_power / np.maximum(v, min_speed), np.nan)


def envelope_limit(v, train: TrainSpec, config: WindowConfig) -> np.ndarray:
    """Upper limit of the tractive effort (their eq. 6 and 7), N/kg of effective mass; inf when both are off.

    Eq. 7: maximum tractive effort c0 below the transition speed, maximum power c2 / v above it.
    Eq. 6: Curtius-Kniffler adhesion mu(v) g m_adh of the driven axles (m_adh = adhesive mass fraction * m).
    """
    v = np.asarray(v, dtype=float)
    limit = np.full(v.shape, np.inf)
    if config.traction_constraint:
        limit = np.minimum(limit, physics.tractive_envelope(v, train.max_tractive_effort, train.max_tractive_power))
    if config.adhesion_constraint and train.adhesive_mass_fraction > 0.0:
        limit = np.minimum(limit, physics.adhesion_limit(v, train.adhesive_mass_fraction, train.rotating_mass_factor))
    return limit


@dataclass
class DifferenceRows:
    """Their eq. 4 for a set of steps k -> k+1 as the linear model y = X theta + e (N/kg of effective mass).

    ``upper`` is the eq. 6/7 constraint X theta <= upper (inf: unconstrained), with its margin included.
    """

    t_end: np.ndarray  # time of sample k+1 (the step's end), s
    x: np.ndarray  # (n, 3): 1, v, v^2 (1 + f_tun tau)
    y: np.ndarray  # f - g - a, N/kg
    upper: np.ndarray  # N/kg
    v: np.ndarray  # speed the resistance is evaluated at (v_k, or the step mean), m/s
    acceleration: np.ndarray  # (v_k+1 - v_k) / dt, m/s^2
    force: np.ndarray  # measured tractive force f of the step, N/kg
    valid: np.ndarray  # bool: usable (speed, power, gap, finite)

    def __len__(self) -> int:
        return int(self.y.shape[0])

    def take(self, index) -> DifferenceRows:
        return DifferenceRows(*(getattr(self, name)[index] for name in _ROW_FIELDS))


_ROW_FIELDS = ("t_end", "x", "y", "upper", "v", "acceleration", "force", "valid")


def difference_rows(
    t,
    v,
    force,
    track_force,
    tunnel_fraction,
    train: TrainSpec,
    config: WindowConfig,
    v_variance=None,
    segment=None,
) -> DifferenceRows:
    """Rows of eq. 4 for consecutive samples (n samples give n - 1 rows).

    t in s, v in m/s, force = measured tractive force per effective mass (N/kg, NaN where unknown),
    track_force g(s) in N/kg, tunnel_fraction 0..1, v_variance in (m/s)^2 (margin of the eq. 6/7
    constraints), segment: run id per sample (a step across a change of segment is not valid).
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    f = np.asarray(force, dtype=float)
    g = np.asarray(track_force, dtype=float)
    tau = np.asarray(tunnel_fraction, dtype=float)
    dt = np.diff(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.diff(v) / dt
    c2 = v * v * (1.0 + train.tunnel_factor * tau)
    per_sample = np.stack([np.ones_like(v), v, c2], axis=1)
    limit = envelope_limit(v, train, config)
    if config.difference_scheme == "forward":
        x = per_sample[:-1]
        f_step, g_step, v_step, lim = f[:-1], g[:-1], v[:-1], limit[:-1]
        speed_ok = v[:-1] >= config.min_speed
    else:  # resistance and track force averaged over the step's ends; trapezoid averages the force too
        x = 0.5 * (per_sample[:-1] + per_sample[1:])
        g_step, v_step = 0.5 * (g[:-1] + g[1:]), 0.5 * (v[:-1] + v[1:])
        if config.difference_scheme == "trapezoid":
            f_step, lim = 0.5 * (f[:-1] + f[1:]), 0.5 * (limit[:-1] + limit[1:])
            speed_ok = (v[:-1] >= config.min_speed) & (v[1:] >= config.min_speed)
        else:  # midpoint: tractive force of sample k held over the step, limited where it was measured
            f_step, lim = f[:-1], limit[:-1]
            speed_ok = v[:-1] >= config.min_speed
    y = f_step - g_step - a
    if v_variance is None:
        margin = np.zeros_like(dt)
    else:
        var = np.asarray(v_variance, dtype=float) * np.ones_like(v)
        with np.errstate(divide="ignore", invalid="ignore"):
            margin = config.constraint_sigma * np.sqrt(var[:-1] + var[1:]) / dt
    upper = lim - g_step - a + margin
    valid = speed_ok & (dt > 0.0) & (dt <= config.max_gap) & np.isfinite(y) & np.all(np.isfinite(x), axis=1)
    valid &= ~np.isnan(upper)
    if segment is not None:
        seg = np.asarray(segment)
        valid &= seg[:-1] == seg[1:]
    return DifferenceRows(t[1:], x, y, upper, v_step, a, f_step, valid)


def regime_from_power(force, acceleration, config: WindowConfig) -> np.ndarray:
    """Driving regime per step from the measured force and acceleration (De Martinis Section 5.1).

    No effort (|f| <= effort_tolerance): coasting. Effort applied and |a| <= cruise_tolerance:
    cruising (electric braking on a descent included, their eq. 7 discussion). Otherwise traction
    (f > 0) or braking (f < 0, regenerated power). NaN force: unknown. force in N/kg, a in m/s^2.
    """
    f = np.asarray(force, dtype=float)
    a = np.asarray(acceleration, dtype=float)
    regime = np.where(f > 0.0, TRACTION, BRAKING)
    regime = np.where(np.abs(a) <= config.cruise_tolerance, CRUISING, regime)
    regime = np.where(np.abs(f) <= config.effort_tolerance, COASTING, regime)
    return np.where(np.isfinite(f) & np.isfinite(a), regime, UNKNOWN).astype(np.uint8)


class StepModel:
    """One step of :func:`difference_rows` (and :func:`tractive_force`, :func:`regime_from_power`) in plain floats.

    The streaming calibrator's per-sample work: the same operations in the same order as the array
    functions, so a valid row is equal bit for bit (tested); for an invalid step only ``None`` is returned.
    """

    def __init__(self, train: TrainSpec, config: WindowConfig) -> None:
        self.config = config
        self.mass = train.effective_mass_kg
        self.eta = train.transmission_efficiency
        self.auxiliary_w = train.auxiliary_power_kw * 1000.0
        self.tunnel_factor = train.tunnel_factor
        self.traction = config.traction_constraint
        self.c0, self.c2 = train.max_tractive_effort, train.max_tractive_power
        self.v_transition = physics.transition_speed(self.c0, self.c2)
        self.adhesion = config.adhesion_constraint and train.adhesive_mass_fraction > 0.0
        self.adhesive_fraction = train.adhesive_mass_fraction
        self.gamma = train.rotating_mass_factor

    def values(self) -> dict[str, float]:
        """The step model by name, as floats (flags 0/1, the difference scheme its index): what the C kernel's Window
        reads (``_kernel.STEP_PARAM_NAMES``)."""
        cfg = self.config
        return {
            "mass": self.mass,
            "eta": self.eta,
            "auxiliary_w": self.auxiliary_w,
            "tunnel_factor": self.tunnel_factor,
            "traction": float(self.traction),
            "c0": self.c0,
            "c2": self.c2,
            "v_transition": self.v_transition,
            "adhesion": float(self.adhesion),
            "adhesive_fraction": self.adhesive_fraction,
            "gamma": self.gamma,
            "gravity": physics.GRAVITY,
            "difference_scheme": float(DIFFERENCE_SCHEMES.index(cfg.difference_scheme)),
            "min_speed": cfg.min_speed,
            "max_gap": cfg.max_gap,
            "constraint_sigma": cfg.constraint_sigma,
            "effort_tolerance": cfg.effort_tolerance,
            "cruise_tolerance": cfg.cruise_tolerance,
            "exclude_braking": float(cfg.exclude_braking),
        }

    def params(self, names: Sequence[str]) -> np.ndarray:
        """The step model as an array in the order of ``names`` (the C kernel's ``STEP_PARAM_NAMES``): by name, so an
        order changed on either side cannot misplace a value; ValueError unless the names are exactly ours."""
        values = self.values()
        if len(names) != len(values) or set(names) != set(values):
            raise ValueError(f"step model names: the kernel has {sorted(names)}, StepModel.values() {sorted(values)}")
        return np.array([values[name] for name in names])

    def force(self, v: float, power_consumed: float, power_regenerated: float) -> float:
        """Measured tractive force per effective mass (tractive_force / M), N/kg; NaN below min_speed."""
        consumed = power_consumed - self.auxiliary_w
        wheel = (self.eta * consumed if consumed > 0.0 else 0.0) - power_regenerated / self.eta
        if consumed < 0.0:
            wheel = wheel + consumed / self.eta
        min_speed = self.config.min_speed
        return wheel / max(v, min_speed) / self.mass if v >= min_speed else math.nan

    def limit(self, v: float) -> float:
        """envelope_limit at a finite speed v (m/s), N/kg."""
        limit = math.inf
        if self.traction:
            if v <= self.v_transition:
                envelope = self.c0 + 0.0 * v
            else:
                envelope = self.c2 / max(v, 1e-12) if v > 0.0 else math.inf
            limit = min(limit, max(envelope, 0.0))
        if self.adhesion:
            mu = 0.161 + 7.5 / (3.6 * v + 44.0)
            limit = min(limit, mu * physics.GRAVITY * self.adhesive_fraction / self.gamma)
        return limit

    def row(self, start: tuple, end: tuple) -> tuple[float, ...] | None:
        """The row of the step between two samples (t s, v m/s, f N/kg, g N/kg, tau, v_variance (m/s)^2, limit N/kg).

        Returns (x0, x1, x2, y, upper, v, acceleration, force) as in DifferenceRows, or None if not valid.
        """
        cfg = self.config
        t0, v0, f0, g0, tau0, var0, lim0 = start
        t1, v1, f1, g1, tau1, var1, lim1 = end
        dt = t1 - t0
        if not (dt > 0.0 and dt <= cfg.max_gap):
            return None
        a = (v1 - v0) / dt
        c20 = v0 * v0 * (1.0 + self.tunnel_factor * tau0)
        scheme = cfg.difference_scheme
        if scheme == "forward":
            x1, x2, f, g, v, lim = v0, c20, f0, g0, v0, lim0
            speed_ok = v0 >= cfg.min_speed
        else:
            c21 = v1 * v1 * (1.0 + self.tunnel_factor * tau1)
            x1, x2 = 0.5 * (v0 + v1), 0.5 * (c20 + c21)
            g, v = 0.5 * (g0 + g1), 0.5 * (v0 + v1)
            if scheme == "trapezoid":
                f, lim = 0.5 * (f0 + f1), 0.5 * (lim0 + lim1)
                speed_ok = v0 >= cfg.min_speed and v1 >= cfg.min_speed
            else:
                f, lim = f0, lim0
                speed_ok = v0 >= cfg.min_speed
        y = f - g - a
        variance = var0 + var1
        margin = cfg.constraint_sigma * math.sqrt(variance) / dt if variance >= 0.0 else math.nan
        upper = lim - g - a + margin
        if not (speed_ok and math.isfinite(y) and math.isfinite(x1) and math.isfinite(x2)) or math.isnan(upper):
            return None
        return (1.0, x1, x2, y, upper, v, a, f)

    def regime(self, force: float, acceleration: float) -> int:
        """regime_from_power of one step (finite force and acceleration)."""
        cfg = self.config
        if abs(force) <= cfg.effort_tolerance:
            return COASTING
        if abs(acceleration) <= cfg.cruise_tolerance:
            return CRUISING
        return TRACTION if force > 0.0 else BRAKING
