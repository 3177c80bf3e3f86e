"""Fault injection for the robustness tests: a physics-consistent scenario, its input bag, faults, recovery.

The scenario is one interstation run on a straight 20 km test line (written by :func:`write_track`):
stand, traction at 80 % of the envelope to 120 km/h, hold, coast to 90 km/h, traction back to
120 km/h, hold, coast to 80 km/h, brake at 0.5 m/s^2, stand. The motion model dv/dt = u - r(v) - g(s)
(g over the train length from the track file) is integrated with RK4 at 0.1 s with a true resistance
10 % off the train file, so the converging UKF has coasting phases to learn from. Sensors at 1 Hz:
GNSS (sigma 3 m per axis, delivered 0.1 s after its stamp) and speed (sigma 0.1 m/s, rounded to
0.1 km/h). Everything is seeded: the same call gives the same bytes.

Inputs are :class:`Event` records (topic, log time, stamp, fields); a fault is a function of the event
list; :func:`write_bag` writes them with :class:`train_calib.bagio.BagWriter`. :func:`recovery` counts
the samples after a fault until the estimates are back within tolerance of the fault-free run.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from train_calib import bagio
from train_calib.estimation import UKFConfig
from train_calib.geodesy import LocalFrame
from train_calib.physics import KMH
from train_calib.track import Track, load_track
from train_calib.train import Davis, TrainSpec, load_train

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
LAT0, LON0 = 52.0, 5.0
LINE_M = 20_000.0
TRAIN_FILE = Path(__file__).resolve().parents[1] / "data" / "small_train.yaml"
TRUE_FACTORS = (1.10, 0.90, 1.10)  # truth = train file x these
GNSS_DELAY_NS = NS // 10  # a fix is delivered (log time) 0.1 s after its stamp


# -- track ------------------------------------------------------------------------------------------


def track_yaml(length_m: float = LINE_M) -> dict[str, Any]:
    """A straight line due north from (52 N, 5 E) with a few gradients."""
    frame = LocalFrame(LAT0, LON0)
    s = np.arange(0.0, length_m + 1.0, 1000.0)
    lat, lon = frame.to_geodetic(np.zeros_like(s), s)
    return {
        "name": "robustness-test-line",
        "length_m": float(length_m),
        "geometry": [{"s_m": float(a), "lat": float(b), "lon": float(c)} for a, b, c in zip(s, lat, lon)],
        "gradients": [
            {"s_m": 0.0, "permille": 0.0},
            {"s_m": 4000.0, "permille": 4.0},
            {"s_m": 9000.0, "permille": -3.0},
            {"s_m": 14000.0, "permille": 0.0},
        ],
        "speed_limits": [{"s_m": 0.0, "kmh": 140.0}],
        "stations": [{"s_m": 300.0, "name": "Alpha"}, {"s_m": length_m - 300.0, "name": "Omega"}],
    }


def write_track(path: Path, length_m: float = LINE_M) -> Path:
    path.write_text(yaml.safe_dump(track_yaml(length_m), sort_keys=False), encoding="utf-8")
    return path


# -- physics ----------------------------------------------------------------------------------------

STAND, TRACTION, HOLD, COAST, BRAKE = range(5)


CONVERGING = UKFConfig.converging()
"""The filter the fault tests run: it learns r, so it is the one a fault could spoil."""


@dataclass
class Phase:
    kind: int
    until: float  # STAND/HOLD: duration (s); TRACTION: target speed; COAST/BRAKE: speed to end at (m/s)


DEFAULT_SCRIPT = (
    Phase(STAND, 30.0),
    Phase(TRACTION, 120 * KMH),
    Phase(HOLD, 60.0),
    Phase(COAST, 90 * KMH),
    Phase(TRACTION, 120 * KMH),
    Phase(HOLD, 40.0),
    Phase(COAST, 80 * KMH),
    Phase(BRAKE, 0.0),
    Phase(STAND, 60.0),
)


@dataclass
class Truth:
    t: np.ndarray  # s since the start, 1 Hz
    s: np.ndarray
    v: np.ndarray
    resistance: Davis


def simulate(track: Track, train: TrainSpec, script: Sequence[Phase] = DEFAULT_SCRIPT, s0: float = 300.0) -> Truth:
    """RK4 at 0.1 s of dv/dt = u - r(v) - g(s) through the phases; sampled at 1 Hz."""
    r0, r1, r2 = (c * f for c, f in zip(train.davis.as_tuple(), TRUE_FACTORS))
    grid = np.arange(0.0, track.length_m + 1.0, 1.0)
    g_grid = track.track_force(grid, train.length_m).tolist()  # g at 1 m spacing: exact between breaks

    def g(s: float) -> float:
        i = min(max(int(s), 0), len(g_grid) - 2)
        return g_grid[i] + (g_grid[i + 1] - g_grid[i]) * (s - i)

    def r(v: float) -> float:
        return r0 + (r1 + r2 * v) * v

    def envelope(v: float) -> float:
        return 0.8 * min(train.max_tractive_effort, train.max_tractive_power / max(v, 0.1))

    h = 0.1
    t = 0.0
    s, v = s0, 0.0
    ts, ss, vs = [0.0], [s], [v]
    for phase in script:
        start = t
        while True:
            if phase.kind in (STAND, HOLD) and t - start >= phase.until - 1e-9:
                break
            if phase.kind == TRACTION and v >= phase.until:
                break
            if phase.kind in (COAST, BRAKE) and v <= phase.until:
                break

            def accel(s_: float, v_: float, kind: int = phase.kind) -> float:
                if kind == STAND or (kind == BRAKE and v_ <= 0.0):
                    return 0.0
                if kind == HOLD:
                    return 0.0
                if kind == TRACTION:
                    return envelope(v_) - r(v_) - g(s_)
                if kind == COAST:
                    return -r(v_) - g(s_)
                return -0.5

            k1s, k1v = v, accel(s, v)
            k2s, k2v = v + 0.5 * h * k1v, accel(s + 0.5 * h * k1s, v + 0.5 * h * k1v)
            k3s, k3v = v + 0.5 * h * k2v, accel(s + 0.5 * h * k2s, v + 0.5 * h * k2v)
            k4s, k4v = v + h * k3v, accel(s + h * k3s, v + h * k3v)
            s += h / 6 * (k1s + 2 * k2s + 2 * k3s + k4s)
            v = max(v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v), 0.0)
            t += h
            ts.append(t)
            ss.append(s)
            vs.append(v)
    t_dense, s_dense, v_dense = np.array(ts), np.array(ss), np.array(vs)
    t1 = np.arange(0.0, t_dense[-1] + 1e-9, 1.0)
    return Truth(t1, np.interp(t1, t_dense, s_dense), np.interp(t1, t_dense, v_dense), Davis(r0, r1, r2))


def shunt(start_s: float, distance_m: float = 200.0, v_max: float = 2.0, a: float = 0.25, pause_s: float = 30.0):
    """A shunting move before a run: stand 20 s, reverse `distance_m` at up to `v_max` m/s (accelerate and brake
    at `a` m/s^2) to `start_s`, stand `pause_s`. Returns its 1 Hz truth (resistance unset) and its duration (s)."""
    t_acc = v_max / a
    d_acc = 0.5 * a * t_acc**2
    t_hold = max(distance_m - 2 * d_acc, 0.0) / v_max
    t_move = 2 * t_acc + t_hold
    duration = 20.0 + t_move + pause_s
    t = np.arange(0.0, duration, 1.0)
    tm = np.clip(t - 20.0, 0.0, t_move)
    v = np.minimum(np.minimum(a * tm, v_max), np.maximum(a * (t_move - tm), 0.0))
    braking = distance_m - 0.5 * a * np.maximum(t_move - tm, 0.0) ** 2
    moved = np.where(
        tm <= t_acc, 0.5 * a * tm**2, np.where(tm <= t_acc + t_hold, d_acc + v_max * (tm - t_acc), braking)
    )
    return Truth(t, start_s + distance_m - moved, v, Davis(0.0, 0.0, 0.0)), duration


def delayed(events: Iterable[Event], seconds: float) -> list[Event]:
    """The events later by `seconds` (stamps and log times)."""
    d = round(seconds * NS)
    return [replace(e, log_ns=e.log_ns + d, stamp_ns=e.stamp_ns + d) for e in events]


# -- input events -----------------------------------------------------------------------------------

GNSS, SPEED, POWER = bagio.GNSS_TOPIC, bagio.SPEED_TOPIC, bagio.POWER_TOPIC


@dataclass
class Event:
    """One input message: topic, log time (delivery order), header stamp and the message fields."""

    topic: str
    log_ns: int
    stamp_ns: int
    fields: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> float:
        """Stamp in s since T0."""
        return (self.stamp_ns - T0) / NS

    def with_fields(self, **changes: Any) -> Event:
        return replace(self, fields={**self.fields, **changes})


def sensor_events(track: Track, truth: Truth, seed: int = 7, t0_ns: int = T0) -> list[Event]:
    """GNSS fixes and speed samples at 1 Hz, in log-time order."""
    rng = np.random.default_rng(seed)
    n = truth.t.size
    e_true, n_true = track.enu_at(truth.s)
    lat, lon = track.frame.to_geodetic(e_true + rng.normal(0.0, 3.0, n), n_true + rng.normal(0.0, 3.0, n))
    speed = np.round(np.maximum(truth.v + rng.normal(0.0, 0.1, n), 0.0) / (0.1 * KMH)) * (0.1 * KMH)
    speed[truth.v == 0.0] = 0.0
    events = []
    for k in range(n):
        stamp = t0_ns + round(truth.t[k] * NS)
        events.append(Event(SPEED, stamp + NS // 50, stamp, {"v": float(speed[k])}))
        cov = [9.0, 0.0, 0.0, 0.0, 9.0, 0.0, 0.0, 0.0, 36.0]
        fix = {"lat": float(lat[k]), "lon": float(lon[k]), "alt": 10.0, "status": 0, "cov": cov, "cov_type": 2}
        events.append(Event(GNSS, stamp + GNSS_DELAY_NS, stamp, fix))
    return sort_events(events)


def sort_events(events: Iterable[Event]) -> list[Event]:
    return sorted(events, key=lambda e: (e.log_ns, e.topic))


def _message(event: Event) -> Any:
    f = event.fields
    header = bagio.make_header(event.stamp_ns, "sensor")
    if event.topic == GNSS:
        status = bagio.msg_class("sensor_msgs/msg/NavSatStatus")(status=int(f["status"]), service=1)
        return bagio.msg_class("sensor_msgs/msg/NavSatFix")(
            header=header,
            status=status,
            latitude=float(f["lat"]),
            longitude=float(f["lon"]),
            altitude=float(f.get("alt", 0.0)),
            position_covariance=np.asarray(f.get("cov", np.zeros(9)), dtype=float),
            position_covariance_type=int(f.get("cov_type", 0)),
        )
    if event.topic == SPEED:
        vec = bagio.msg_class("geometry_msgs/msg/Vector3")
        twist = bagio.msg_class("geometry_msgs/msg/Twist")(
            linear=vec(x=float(f["v"]), y=float(f.get("vy", 0.0)), z=float(f.get("vz", 0.0))),
            angular=vec(x=0.0, y=0.0, z=float(f.get("wz", 0.0))),
        )
        return bagio.msg_class("geometry_msgs/msg/TwistStamped")(header=header, twist=twist)
    return bagio.msg_class("train_calib_msgs/msg/TractionPower")(
        header=header, power_consumed=float(f["consumed"]), power_regenerated=float(f["regenerated"])
    )


def write_bag(path: Path, events: Iterable[Event], topics: Iterable[str] | None = None) -> Path:
    events = list(events)
    names = set(topics) if topics is not None else {e.topic for e in events} | {GNSS, SPEED}
    with bagio.BagWriter(path, {t: ty for t, ty in bagio.INPUT_TOPICS.items() if t in names}) as writer:
        for e in events:
            writer.write(e.topic, _message(e), e.log_ns)
    return path


# -- the scenario -----------------------------------------------------------------------------------


@dataclass
class Scenario:
    track_path: Path
    train_path: Path
    track: Track
    train: TrainSpec
    truth: Truth
    events: list[Event]

    def window(self, phase_start: float, duration: float) -> tuple[float, float]:
        return phase_start, phase_start + duration

    def time_at_speed(self, v: float, after: float = 0.0, falling: bool = False) -> float:
        """First time (s) after `after` when the true speed crosses v (upwards, or downwards if falling)."""
        t, s = self.truth.t, self.truth.v
        ok = (t > after) & ((s <= v) if falling else (s >= v))
        return float(t[np.argmax(ok)])


def make_scenario(directory: Path, script: Sequence[Phase] = DEFAULT_SCRIPT, seed: int = 7) -> Scenario:
    track_path = write_track(directory / "robust_track.yaml")
    track, train = load_track(track_path), load_train(TRAIN_FILE)
    truth = simulate(track, train, script)
    return Scenario(track_path, TRAIN_FILE, track, train, truth, sensor_events(track, truth, seed))


# -- comparison with the fault-free run ---------------------------------------------------------------


@dataclass(frozen=True)
class Tolerance:
    """Back within tolerance of the fault-free run: s within 10 m, v within 0.2 m/s and r(v) at 80 and 120 km/h
    within 2 % or within the fault-free estimate's own standard deviation of r(v), whichever is larger (while
    the filter is still learning, its estimate is that uncertain)."""

    s_m: float = 10.0
    v_ms: float = 0.2
    r_rel: float = 0.02
    speeds: tuple[float, ...] = (80 * KMH, 120 * KMH)


def _r(e: Any, v: float) -> float:
    return e.r0 + (e.r1 + e.r2 * v) * v


def _r_std(e: Any, v: float) -> float:
    cov = np.asarray(e.covariance, dtype=float).reshape(5, 5)[2:, 2:]
    g = np.array([1.0, v, v * v])
    return float(math.sqrt(max(g @ cov @ g, 0.0)))


def within(ref: Any, got: Any, tol: Tolerance) -> bool:
    if abs(ref.s - got.s) > tol.s_m or abs(ref.v - got.v) > tol.v_ms:
        return False
    return all(abs(_r(got, v) - _r(ref, v)) <= max(tol.r_rel * _r(ref, v), _r_std(ref, v)) for v in tol.speeds)


def recovery(
    reference: Sequence[Any],
    faulty: Sequence[Any],
    fault_end_ns: int,
    tol: Tolerance = Tolerance(),
    stamp_map: Callable[[Any], int] | None = None,
) -> int:
    """Samples after the fault (stamps > fault_end_ns, matched by stamp) until the estimates stay within `tol`.

    0: within tolerance from the first sample after the fault. A reference sample the faulty run lacks counts as
    out of tolerance (data lost). ``stamp_map``: faulty estimate -> reference stamp (faults that move the stamps).
    Returns len(after) + 1 when never back within tolerance.
    """
    got = {(stamp_map(e) if stamp_map else e.stamp_ns): e for e in faulty}
    after = [e for e in reference if e.stamp_ns > fault_end_ns]
    last_bad = -1
    for i, ref in enumerate(after):
        e = got.get(ref.stamp_ns)
        if e is None or not within(ref, e, tol):
            last_bad = i
    if last_bad == len(after) - 1 and after:
        return len(after) + 1
    return last_bad + 1


def final_difference(reference: Sequence[Any], faulty: Sequence[Any]) -> float:
    """Largest relative difference of the final r(v) at 80 and 120 km/h (the lasting effect of a fault)."""
    a, b = reference[-1], faulty[-1]
    return max(abs(_r(b, v) - _r(a, v)) / _r(a, v) for v in Tolerance().speeds)


def max_deviation(reference: Sequence[Any], faulty: Sequence[Any], start_ns: int = 0) -> dict[str, float]:
    """Largest |difference| of s, v and relative r(v) (at 80, 120 km/h) over samples with stamp > start_ns."""
    got = {e.stamp_ns: e for e in faulty}
    out = {"s": 0.0, "v": 0.0, "r": 0.0}
    for ref in reference:
        e = got.get(ref.stamp_ns)
        if e is None or ref.stamp_ns <= start_ns:
            continue
        out["s"] = max(out["s"], abs(e.s - ref.s))
        out["v"] = max(out["v"], abs(e.v - ref.v))
        for v in Tolerance().speeds:
            out["r"] = max(out["r"], abs(_r(e, v) - _r(ref, v)) / _r(ref, v))
    return out


def physical(estimates: Iterable[Any]) -> list[str]:
    """Problems with published estimates: a non-finite field, a negative r, an asymmetric or non-PD covariance."""
    problems = []
    for e in estimates:
        values = [e.s, e.v, e.r0, e.r1, e.r2, e.effort, e.acceleration]
        cov = np.asarray(e.covariance, dtype=float).reshape(5, 5)
        if not all(math.isfinite(x) for x in values) or not np.all(np.isfinite(cov)):
            problems.append(f"{e.stamp_ns}: non-finite value")
        elif min(e.r0, e.r1, e.r2) < 0.0:
            problems.append(f"{e.stamp_ns}: negative resistance {e.r0, e.r1, e.r2}")
        elif not np.array_equal(cov, cov.T) or np.linalg.eigvalsh(cov)[0] <= 0.0:
            problems.append(f"{e.stamp_ns}: covariance not symmetric positive definite")
    return problems


Fault = Callable[[list[Event]], list[Event]]


# -- faults -------------------------------------------------------------------------------------------


def in_window(e: Event, t0: float, t1: float, topic: str | None = None) -> bool:
    return t0 <= e.t < t1 and (topic is None or e.topic == topic)


def set_fields(events: list[Event], t0: float, t1: float, topic: str, **changes: Any) -> list[Event]:
    """Every message of `topic` stamped in [t0, t1) gets the field values (a callable: of the event)."""
    out = []
    for e in events:
        if in_window(e, t0, t1, topic):
            e = e.with_fields(**{k: (v(e) if callable(v) else v) for k, v in changes.items()})
        out.append(e)
    return out


def remove(events: list[Event], t0: float, t1: float, topic: str) -> list[Event]:
    return [e for e in events if not in_window(e, t0, t1, topic)]


def shift_fix(track: Track, e: Event, along_m: float = 0.0, east_m: float = 0.0) -> dict[str, float]:
    """Fields of a fix moved along the (northbound) line and east of it."""
    east, north = track.to_enu(e.fields["lat"], e.fields["lon"])
    lat, lon = track.frame.to_geodetic(float(east) + east_m, float(north) + along_m)
    return {"lat": float(lat), "lon": float(lon)}


def moved_fixes(track: Track, events: list[Event], t0: float, t1: float, along_m: float = 0.0, east_m: float = 0.0):
    out = []
    for e in events:
        if in_window(e, t0, t1, GNSS):
            e = e.with_fields(**shift_fix(track, e, along_m, east_m))
        out.append(e)
    return out


def duplicated(events: list[Event], t0: float, t1: float, topic: str, **changes: Any) -> list[Event]:
    """Every message of `topic` in the window sent twice (the copy with `changes`), right after the original."""
    out = []
    for e in events:
        out.append(e)
        if in_window(e, t0, t1, topic):
            out.append(replace(e.with_fields(**changes), log_ns=e.log_ns + 1000))
    return sort_events(out)


def swapped(events: list[Event], t0: float, t1: float, topic: str) -> list[Event]:
    """Consecutive messages of `topic` in the window delivered in swapped pairs (out-of-order stamps)."""
    idx = [i for i, e in enumerate(events) if in_window(e, t0, t1, topic)]
    out = list(events)
    for a, b in zip(idx[0::2], idx[1::2]):
        out[a], out[b] = replace(events[b], log_ns=events[a].log_ns), replace(events[a], log_ns=events[b].log_ns)
    return sort_events(out)


def restamped(events: list[Event], t0: float, topic: str | None, offset_s: float) -> list[Event]:
    """Stamps of `topic` (every topic: None) from t0 on shifted by offset_s (log times unchanged)."""
    d = round(offset_s * NS)
    return [replace(e, stamp_ns=e.stamp_ns + d) if e.t >= t0 and topic in (None, e.topic) else e for e in events]


# -- the catalogue ------------------------------------------------------------------------------------

NAN, INF = float("nan"), float("inf")
FAULT_START = 200.0  # s: in the first coasting phase, where the converging filter learns r


@dataclass(frozen=True)
class FaultCase:
    """One fault class: how it is injected (events -> events), when, and what the ingest must count."""

    name: str
    inject: Callable[[Scenario], list[Event]]
    window: tuple[float, float]  # s after T0: the fault lasts [start, end)
    drops: dict[str, dict[str, int]] = field(default_factory=dict)  # stream -> reason -> count
    repaired: dict[str, dict[str, int]] = field(default_factory=dict)
    stamp_shift: tuple[float, float] | None = None  # (from s, by s): the fault moved the stamps (clock faults)
    new_run: bool = False  # the fault starts a new run (the estimates restart from the prior there)
    # bounds for the converging filter (measured values + margin; docs/reliability.md has the measurements)
    max_recovery: int = 10  # samples after the fault until back within Tolerance() of the fault-free run
    max_s: float = 10.0  # m, largest |s - s_fault_free| over the run
    max_v: float = 0.5  # m/s, largest |v - v_fault_free| over the run
    max_final: float = 0.01  # largest relative difference of the final r(v) at 80 and 120 km/h

    removed: int = 0  # speed messages the fault removed (a silent stream)

    @property
    def lost(self) -> int:
        """Estimates the fault-free run has and the faulty one cannot have: the speed samples the fault removed
        or spoiled (a duplicate is an extra message: the original is kept)."""
        spoiled = sum(n for reason, n in self.drops.get("speed", {}).items() if reason != "duplicate")
        return spoiled + self.removed


def _fields(t0: float, t1: float, topic: str, **changes: Any) -> Callable[[Scenario], list[Event]]:
    return lambda sc: set_fields(list(sc.events), t0, t1, topic, **changes)


def _plus(dv: float) -> Callable[[Event], float]:
    return lambda e: e.fields["v"] + dv


def _slip(e: Event) -> float:  # wheel slip: the speed reads 15 or 30 m/s high, alternating
    return e.fields["v"] + (15.0 if round(e.t) % 2 == 0 else 30.0)


S0 = FAULT_START
CASES: tuple[FaultCase, ...] = (
    FaultCase("gnss_latitude_nan", _fields(S0, S0 + 10, GNSS, lat=NAN), (S0, S0 + 10), {"gnss": {"nan": 10}}),
    FaultCase("gnss_longitude_inf", _fields(S0, S0 + 10, GNSS, lon=INF), (S0, S0 + 10), {"gnss": {"nan": 10}}),
    FaultCase("gnss_altitude_nan", _fields(S0, S0 + 10, GNSS, alt=NAN), (S0, S0 + 10)),
    FaultCase(
        "gnss_covariance_nan",
        _fields(S0, S0 + 10, GNSS, cov=[NAN] * 9),
        (S0, S0 + 10),
        repaired={"gnss": {"bad_covariance": 10}},
    ),
    FaultCase(
        "gnss_covariance_negative",
        _fields(S0, S0 + 10, GNSS, cov=[-9.0, 0.0, 0.0, 0.0, -9.0, 0.0, 0.0, 0.0, 1.0]),
        (S0, S0 + 10),
        repaired={"gnss": {"bad_covariance": 10}},
    ),
    FaultCase("speed_nan", _fields(S0, S0 + 10, SPEED, v=NAN), (S0, S0 + 10), {"speed": {"nan": 10}}, max_recovery=80),
    FaultCase("speed_inf", _fields(S0, S0 + 10, SPEED, v=INF), (S0, S0 + 10), {"speed": {"nan": 10}}, max_recovery=80),
    FaultCase("speed_unused_fields_nan", _fields(S0, S0 + 10, SPEED, vy=NAN, vz=INF, wz=NAN), (S0, S0 + 10)),
    FaultCase(
        "speed_negative",
        _fields(S0, S0 + 10, SPEED, v=lambda e: -e.fields["v"]),
        (S0, S0 + 10),
        {"speed": {"negative_speed": 10}},
        max_recovery=80,
    ),
    FaultCase(
        "speed_spike", _fields(S0 + 20, S0 + 21, SPEED, v=_plus(15.0)), (S0 + 20, S0 + 21), {"speed": {"speed_jump": 1}}
    ),
    FaultCase(
        "speed_slip_3s",
        _fields(S0 + 20, S0 + 23, SPEED, v=_plus(15.0)),
        (S0 + 20, S0 + 23),
        {"speed": {"speed_jump": 3}},
    ),
    FaultCase(
        "speed_slip_5s_varying",
        _fields(S0 + 20, S0 + 25, SPEED, v=_slip),
        (S0 + 20, S0 + 25),
        {"speed": {"speed_jump": 5}},
        max_recovery=250,
    ),
    FaultCase("gnss_no_fix", _fields(S0, S0 + 30, GNSS, status=-1), (S0, S0 + 30), {"gnss": {"no_fix": 30}}),
    FaultCase(
        "gnss_jump_50m",
        lambda sc: moved_fixes(sc.track, list(sc.events), S0 + 20, S0 + 21, along_m=50.0),
        (S0 + 20, S0 + 21),
    ),
    FaultCase(
        "gnss_jump_55m_3s",
        lambda sc: moved_fixes(sc.track, list(sc.events), S0 + 20, S0 + 23, along_m=55.0),
        (S0 + 20, S0 + 23),
    ),
    FaultCase(
        "gnss_jump_100m_5s",
        lambda sc: moved_fixes(sc.track, list(sc.events), S0 + 20, S0 + 25, along_m=100.0),
        (S0 + 20, S0 + 28),
        {"gnss": {"jump": 4}},
    ),
    FaultCase(
        "gnss_jump_500m_5s",
        lambda sc: moved_fixes(sc.track, list(sc.events), S0 + 20, S0 + 25, along_m=-500.0),
        (S0 + 20, S0 + 28),
        {"gnss": {"jump": 4}},
    ),
    FaultCase(
        "gnss_off_track_200m",
        lambda sc: moved_fixes(sc.track, list(sc.events), S0 + 20, S0 + 40, east_m=200.0),
        (S0 + 20, S0 + 40),
        {"gnss": {"off_track": 20}},
    ),
    FaultCase(
        "duplicate_stamps",
        lambda sc: duplicated(duplicated(list(sc.events), S0, S0 + 60, SPEED, v=0.0), S0, S0 + 60, GNSS),
        (S0, S0 + 60),
        {"speed": {"duplicate": 60}, "gnss": {"duplicate": 60}},
    ),
    FaultCase(
        "out_of_order_pairs",
        lambda sc: swapped(swapped(list(sc.events), S0, S0 + 60, SPEED), S0, S0 + 60, GNSS),
        (S0, S0 + 60),
        {"speed": {"out_of_order": 30}, "gnss": {"out_of_order": 30}},
        # half the samples of the first coasting phase lost: r waits for the next one. Measured with the coasting
        # look-ahead: recovery 231, final 1.11 %; before it 41 and 0.73 %, helped by 5 traction steps the
        # reference took as coasting at 273-277 s. Over scenario seeds 1-8 (the same fault, other noise draws):
        # recovery 16..406 and final 0.19..1.44 % before, 16..205 and 0.09..0.70 % with it
        max_recovery=250,
        max_final=0.015,
        max_v=1.5,
    ),
    FaultCase(
        "tunnel_no_fix_120s",
        _fields(S0, S0 + 120, GNSS, status=-1, lat=NAN, lon=NAN),
        (S0, S0 + 120),
        {"gnss": {"no_fix": 120}},
        max_s=12.0,
    ),
    FaultCase("tunnel_silent_120s", lambda sc: remove(list(sc.events), S0, S0 + 120, GNSS), (S0, S0 + 120), max_s=12.0),
    FaultCase(
        "speed_silent_60s",
        lambda sc: remove(list(sc.events), S0, S0 + 60, SPEED),
        (S0, S0 + 60),
        max_recovery=230,
        max_v=1.0,
        removed=60,
    ),
    FaultCase(
        "clock_reset_1h_back",
        lambda sc: restamped(list(sc.events), 300.0, None, -3600.0),
        (300.0, 300.0),
        stamp_shift=(300.0, -3600.0),
        new_run=True,
        max_recovery=180,
        max_s=15.0,
    ),
    FaultCase(
        "clock_step_10s_back",
        lambda sc: restamped(list(sc.events), 300.0, None, -10.0),
        (300.0, 300.0),
        stamp_shift=(300.0, -10.0),
        new_run=True,
        max_recovery=180,
        max_s=15.0,
    ),
    FaultCase(
        "gnss_clock_1h_behind",
        lambda sc: restamped(list(sc.events), 300.0, GNSS, -3600.0),
        (300.0, 10_000.0),
        {"gnss": {"stale": 469}},
        max_s=12.0,
    ),
)
CASE_BY_NAME = {c.name: c for c in CASES}


def reference_stamp(case: FaultCase) -> Callable[[Any], int] | None:
    """Estimate of the faulty run -> the stamp of the same sample in the fault-free run (clock faults: the
    samples of the new run, after the reset, carry shifted stamps)."""
    if case.stamp_shift is None:
        return None
    by_ns = round(case.stamp_shift[1] * NS)
    return lambda e: e.stamp_ns - by_ns if e.run_id >= 1 else e.stamp_ns


def deep_size(obj: Any) -> int:
    """Bytes held by an object graph (containers, instance attributes, numpy buffers), each object once."""
    import collections
    import types

    seen: set[int] = set()
    stack = [obj]
    total = 0
    skip = (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType, types.MethodType)
    while stack:
        o = stack.pop()
        if id(o) in seen or isinstance(o, skip):
            continue
        seen.add(id(o))
        total += sys.getsizeof(o, 0)
        if isinstance(o, np.ndarray):
            total += o.nbytes if o.base is None else 0
            continue
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, (list, tuple, set, frozenset, collections.deque)):
            stack.extend(o)
        if hasattr(o, "__dict__"):
            stack.append(vars(o))
        for name in getattr(type(o), "__slots__", ()):
            if hasattr(o, name):
                stack.append(getattr(o, name))
    return total
