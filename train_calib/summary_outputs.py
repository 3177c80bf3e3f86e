"""The recorded outputs of a replay as arrays (no ROS): ``read_outputs(bag)``, and the topics and units they use.

:mod:`train_calib.summary` computes summary.json from them, :mod:`train_calib.summary_text` prints it.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .bagio import iter_bag, stamp_ns
from .estimation.records import EFFORT_COMPUTED
from .measurement import track_force_integral_of
from .window import WindowFit

RESISTANCE = "/train_calib/resistance"
MEASUREMENT = "/train_calib/measurement"
REGIME = "/train_calib/regime"
FEATURES = "/train_calib/features"
DIAGNOSTICS = "/diagnostics"
WINDOW = "/train_calib/window_resistance"
COEFFS = ("r0", "r1", "r2")
UNITS = {"r0": "N/kg", "r1": "N/(kg m/s)", "r2": "N/(kg (m/s)^2)"}
REFERENCE_SPEEDS_KMH = (40, 80, 120)
"""The speeds (km/h) at which summary.json and the printed summary give r(v)."""
WINDOW_FIELDS = ("run_id", "window_length", "sample_count", "gof_kind", "gof_value", "a", "b", "c", "r0", "r1", "r2",
                 "regime", "ill_posed", "speed_span")  # fmt: skip


@dataclass
class Outputs:
    """The recorded outputs of a replay as arrays (SI units; t in s since the first measurement)."""

    t0_ns: int = 0
    meas: dict[str, np.ndarray] = field(default_factory=dict)  # t, s, v, run_id, speed_limit, s_measured
    est: dict[str, np.ndarray] = field(default_factory=dict)  # t, run_id, s, v, r0..r2, std_r0..2, effort, ...
    regime: dict[str, np.ndarray] = field(default_factory=dict)  # t, regime, v, run_id
    features: list[dict[str, Any]] = field(default_factory=list)
    window: dict[str, Any] | None = None  # the last well-posed /train_calib/window_resistance (window_calib_node)
    window_count: int = 0
    windows: list[WindowFit] = field(default_factory=list)  # every /train_calib/window_resistance, in order
    diagnostics: dict[str, dict[str, str]] = field(default_factory=dict)  # node -> last status values
    diagnostics_level: dict[str, int] = field(default_factory=dict)
    diagnostics_message: dict[str, str] = field(default_factory=dict)
    counts: Counter = field(default_factory=Counter)
    last_r_covariance: np.ndarray | None = None  # 3x3, of the last /train_calib/resistance message


def plain(value: Any) -> Any:
    """A JSON value of a number, array or flag (NaN and inf: None)."""
    if isinstance(value, (np.ndarray, list, tuple)):
        return [plain(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    return value


def read_outputs(bag: str | Path) -> Outputs:
    """Decode the output topics of a recorded bag (directory or output.mcap)."""
    out = Outputs()
    meas: list[tuple] = []
    est: list[tuple] = []
    reg: list[tuple] = []
    for m in iter_bag(bag):
        out.counts[m.topic] += 1
        if m.topic not in (MEASUREMENT, RESISTANCE, REGIME, FEATURES, DIAGNOSTICS, WINDOW):
            continue
        msg = m.decode()
        if m.topic == MEASUREMENT:
            meas.append(
                (stamp_ns(msg.header), msg.s, msg.v, msg.run_id, msg.speed_limit, msg.s_measured, msg.track_force,
                 msg.tunnel_fraction, msg.power_valid, msg.power_consumed, msg.power_regenerated,
                 track_force_integral_of(msg), msg.s_variance, msg.v_variance)
            )  # fmt: skip
        elif m.topic == RESISTANCE:
            cov = np.asarray(msg.covariance, dtype=float).reshape(5, 5)
            std = np.sqrt(np.maximum(np.diag(cov), 0.0))
            out.last_r_covariance = cov[2:, 2:]
            est.append(
                (stamp_ns(msg.header), msg.run_id, msg.s, msg.v, msg.r0, msg.r1, msg.r2, std[2], std[3], std[4],
                 msg.effort, msg.acceleration, msg.health, msg.effort_known, msg.nis,
                 getattr(msg, "effort_source", EFFORT_COMPUTED),  # bags recorded before effort_source: computed
                 msg.resistance, msg.track_force, msg.v_measured)
            )  # fmt: skip
        elif m.topic == REGIME:
            reg.append((stamp_ns(msg.header), msg.regime, msg.v, msg.run_id))
        elif m.topic == WINDOW:
            out.window_count += 1
            fit = window_fit_from_msg(msg)
            window_pooled_from_msg(fit, msg)
            out.windows.append(fit)
            if not fit.ill_posed:
                out.window = {name: plain(getattr(fit, name)) for name in WINDOW_FIELDS if name != "ill_posed"}
                out.window["stamp_ns"] = fit.stamp_ns
        elif m.topic == FEATURES:
            f = {
                name: plain(getattr(msg, name))
                for name in msg.__dataclass_fields__
                if name not in ("header", "__msgtype__")
            }
            f["stamp_ns"] = stamp_ns(msg.header)
            out.features.append(f)
        else:
            for status in msg.status:
                out.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}
                level = status.level
                out.diagnostics_level[status.name] = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
                out.diagnostics_message[status.name] = status.message
    t0 = meas[0][0] if meas else (est[0][0] if est else 0)
    out.t0_ns = t0
    if meas:
        a = list(zip(*meas))
        out.meas = {
            "t": (np.array(a[0], dtype=np.int64) - t0) * 1e-9,
            "s": np.array(a[1]),
            "v": np.array(a[2]),
            "run_id": np.array(a[3], dtype=np.int64),
            "speed_limit": np.array(a[4]),
            "s_measured": np.array(a[5], dtype=bool),
            "track_force": np.array(a[6], dtype=float),
            "tunnel_fraction": np.array(a[7], dtype=float),
            "power_valid": np.array(a[8], dtype=bool),
            "power_consumed": np.array(a[9], dtype=float),
            "power_regenerated": np.array(a[10], dtype=float),
            "track_force_integral": np.array(a[11], dtype=float),  # NaN in bags recorded before the field
            "s_variance": np.array(a[12], dtype=float),
            "v_variance": np.array(a[13], dtype=float),
        }
    if est:
        a = list(zip(*est))
        names = ("t", "run_id", "s", "v", "r0", "r1", "r2", "std_r0", "std_r1", "std_r2", "effort", "acceleration",
                 "health", "effort_known", "nis", "effort_source",
                 "resistance", "track_force", "v_measured")  # fmt: skip
        out.est = {n: np.array(col) for n, col in zip(names, a)}
        out.est["t"] = (np.array(a[0], dtype=np.int64) - t0) * 1e-9
    if reg:
        a = list(zip(*reg))
        out.regime = {
            "t": (np.array(a[0], dtype=np.int64) - t0) * 1e-9,
            "regime": np.array(a[1], dtype=np.int64),
            "v": np.array(a[2]),
            "run_id": np.array(a[3], dtype=np.int64),
        }
    return out


def window_fit_from_msg(msg: Any) -> WindowFit:
    """A WindowResistance message as a WindowFit (``estimate`` = the published r0, r1, r2 of a well-posed window)."""
    values = {name: getattr(msg, name) for name in WINDOW_FIELDS}
    values = {k: (bool(v) if k == "ill_posed" else int(v) if isinstance(v, (int, np.integer)) else float(v))
              for k, v in values.items()}  # fmt: skip
    if not values["ill_posed"]:
        values["estimate"] = (values["r0"], values["r1"], values["r2"])
    return WindowFit(stamp_ns=stamp_ns(msg.header), **values)


def window_pooled_from_msg(fit: WindowFit, msg: Any) -> None:
    """The window's resistance at its mean speed and the pooled r(v) of a WindowResistance message into its WindowFit
    (NaN / 0 windows from bags recorded before the fields)."""
    nan = math.nan
    fit.resistance_speed = float(getattr(msg, "resistance_speed", nan))
    fit.resistance_at_speed = float(getattr(msg, "resistance_at_speed", nan))
    fit.resistance_at_speed_std = float(getattr(msg, "resistance_at_speed_std", nan))
    fit.pooled = tuple(float(getattr(msg, f"pooled_{c}", nan)) for c in COEFFS)  # type: ignore[assignment]
    fit.pooled_covariance = tuple(float(x) for x in getattr(msg, "pooled_covariance", ()))
    fit.pooled_windows = int(getattr(msg, "pooled_windows", 0))
