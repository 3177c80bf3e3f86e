"""Streaming sliding-window calibration: one Measurement in, the fit of the window ending there out."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from ..measurement import Measurement, MeasurementSeries
from ..train import TrainSpec
from .config import WindowConfig
from .fit import WindowFit, fit_rows
from .model import UNKNOWN, DifferenceRows, difference_rows, regime_from_power, tractive_force


class _RowBuffer:
    """The difference rows of the current window, oldest first, in preallocated arrays."""

    def __init__(self, capacity: int = 64) -> None:
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        self.end_ns = np.empty(capacity, dtype=np.int64)
        self.t_end = np.empty(capacity)
        self.x = np.empty((capacity, 3))
        self.y = np.empty(capacity)
        self.upper = np.empty(capacity)
        self.v = np.empty(capacity)
        self.acceleration = np.empty(capacity)
        self.force = np.empty(capacity)
        self.valid = np.empty(capacity, dtype=bool)
        self.regime = np.empty(capacity, dtype=np.uint8)
        self.start = self.stop = 0

    _NAMES = ("end_ns", "t_end", "x", "y", "upper", "v", "acceleration", "force", "valid", "regime")

    def clear(self) -> None:
        self.start = self.stop = 0

    def __len__(self) -> int:
        return self.stop - self.start

    def append(self, end_ns: int, row: DifferenceRows, regime: int) -> None:
        if self.stop == len(self.y):
            live = {name: getattr(self, name)[self.start : self.stop].copy() for name in self._NAMES}
            if self.start == 0:
                self._alloc(2 * len(self.y))
            self.start, self.stop = 0, len(live["y"])
            for name, values in live.items():
                getattr(self, name)[: self.stop] = values
        i = self.stop
        self.end_ns[i] = end_ns
        self.t_end[i], self.x[i], self.y[i], self.upper[i] = row.t_end[0], row.x[0], row.y[0], row.upper[0]
        self.v[i], self.acceleration[i], self.force[i] = row.v[0], row.acceleration[0], row.force[0]
        self.valid[i], self.regime[i] = row.valid[0], regime
        self.stop += 1

    def expire(self, min_ns: int) -> None:
        """Drop the steps that end at or before min_ns (stamps in ns, so windows of whole seconds are exact)."""
        while self.start < self.stop and self.end_ns[self.start] <= min_ns:
            self.start += 1

    def view(self) -> tuple[DifferenceRows, np.ndarray]:
        s = slice(self.start, self.stop)
        rows = DifferenceRows(self.t_end[s], self.x[s], self.y[s], self.upper[s], self.v[s], self.acceleration[s],
                              self.force[s], self.valid[s])  # fmt: skip
        return rows, self.regime[s]


class WindowCalibrator:
    """De Martinis & Corman's online calibration over a sliding window of ``config.window_length`` s.

    ``update`` takes each Measurement of a run with the sample's driving regime (None, UNKNOWN or
    ``regime_source`` power: derived from the measured force and acceleration) and returns the fit of
    the window ending at that sample, or None when the sample carries no power (the method is
    inactive without it), is out of order or not finite, or no step has been completed yet. A new
    run_id starts a new window; the published values of the last well-posed window are kept across
    runs (same train). ``counts`` tallies samples and fits by outcome for diagnostics.
    """

    def __init__(self, train: TrainSpec, config: WindowConfig | None = None) -> None:
        self.train = train
        self.config = config or WindowConfig()
        self.counts: Counter[str] = Counter()
        self.last_fit: WindowFit | None = None
        self._rows = _RowBuffer(max(16, int(2 * self.config.window_length) + 4))
        self._origin_ns: int | None = None
        self._last: tuple | None = None  # (stamp_ns, t, v, f, g, tau, v_variance, regime, run_id)

    def set_config(self, config: WindowConfig) -> None:
        """New settings: the window restarts (its steps depend on them); published values are kept."""
        self.config = config
        self._rows = _RowBuffer(max(16, int(2 * config.window_length) + 4))
        self._last = None

    def reset(self) -> None:
        """Forget the window and the published values (a different train)."""
        self._rows.clear()
        self._last = None
        self._origin_ns = None
        self.last_fit = None

    def update(self, m: Measurement, regime: int | None = None) -> WindowFit | None:
        cfg = self.config
        if not all(math.isfinite(value) for value in (m.v, m.track_force, m.tunnel_fraction, m.v_variance)) or (
            m.power_valid and not (math.isfinite(m.power_consumed) and math.isfinite(m.power_regenerated))
        ):
            self.counts["non_finite"] += 1
            return None
        if self._last is not None and m.run_id != self._last[8]:
            self._rows.clear()
            self._last = None
            self.counts["new_run"] += 1
        if self._last is not None and m.stamp_ns <= self._last[0]:
            self.counts["out_of_order"] += 1
            return None
        if self._origin_ns is None:
            self._origin_ns = m.stamp_ns
        t = (m.stamp_ns - self._origin_ns) * 1e-9
        if m.power_valid:
            force = float(tractive_force(m.v, m.power_consumed, m.power_regenerated, self.train, cfg.min_speed))
            force /= self.train.effective_mass_kg
        else:
            force = math.nan
        if cfg.regime_source == "power" or regime == UNKNOWN:
            regime = None
        sample = (m.stamp_ns, t, m.v, force, m.track_force, m.tunnel_fraction, m.v_variance, regime, m.run_id)
        previous, self._last = self._last, sample
        if previous is not None:
            _, t0, v0, f0, g0, tau0, var0, regime0, _ = previous
            row = difference_rows(
                (t0, t), (v0, m.v), (f0, force), (g0, m.track_force), (tau0, m.tunnel_fraction), self.train, cfg,
                v_variance=(var0, m.v_variance),
            )  # fmt: skip
            if regime0 is None:
                regime0 = int(regime_from_power(row.force, row.acceleration, cfg)[0])
            self._rows.append(m.stamp_ns, row, regime0)
            if not row.valid[0]:
                self.counts["invalid_step"] += 1
        if not m.power_valid:
            self.counts["no_power"] += 1
            return None
        if m.v < cfg.min_speed:
            self.counts["below_min_speed"] += 1
        self._rows.expire(m.stamp_ns - round(cfg.window_length * 1e9))
        if len(self._rows) == 0:
            return None
        rows, regimes = self._rows.view()
        fit = fit_rows(rows, regimes, self.train, cfg, stamp_ns=m.stamp_ns, run_id=m.run_id, previous=self.last_fit)
        self.counts["ill_posed" if fit.ill_posed else "well_posed"] += 1
        if fit.dropped_constraints:
            self.counts["windows_with_dropped_constraints"] += 1
        self.last_fit = fit
        return fit


def calibrate_series(
    series: MeasurementSeries, train: TrainSpec, config: WindowConfig | None = None, regimes=None
) -> list[WindowFit]:
    """Run the streaming calibrator over a whole series (offline); one WindowFit per sample that yields one.

    regimes: optional DrivingRegime per sample (e.g. from the regime classifier); None: from power.
    """
    calibrator = WindowCalibrator(train, config)
    out = []
    for i in range(len(series)):
        fit = calibrator.update(series[i], None if regimes is None else int(regimes[i]))
        if fit is not None:
            out.append(fit)
    return out
