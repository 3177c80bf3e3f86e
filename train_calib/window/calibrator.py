"""Streaming sliding-window calibration: one Measurement in, the fit of the window ending there out."""

from __future__ import annotations

import math
from collections import Counter, deque

import numpy as np

from ..measurement import Measurement, MeasurementSeries
from ..train import TrainSpec
from .config import WindowConfig
from .fast import FastFit
from .fit import WindowFit, fit_design
from .model import BRAKING, UNKNOWN, StepModel
from .pooled import PooledResistance, WindowEquations


class _RowBuffer:
    """The rows of the current window the fit uses, oldest first, in preallocated arrays (x and y side by side)."""

    def __init__(self, capacity: int = 64) -> None:
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        self.end_ns = np.empty(capacity, dtype=np.int64)
        self.xy = np.empty((capacity, 4))  # x (1, v, v^2 (1 + f_tun tau)) and y, N/kg; the row's speed v is x1
        self.upper = np.empty(capacity)  # N/kg
        self.upper_tol = np.empty(capacity)  # upper + 1e-12 max(1, |upper|), the solver's feasibility test
        self.negative = np.empty(capacity, dtype=bool)  # a negative entry in x
        self.start = self.stop = 0
        self.negatives = 0
        self.below_zero = 0  # rows with upper_tol < 0 (infeasible at r = 0)
        # (end_ns, v) of the rows that are the fastest (slowest) of the rows after them: [0] is the window's
        self.fastest: deque[tuple[int, float]] = deque()
        self.slowest: deque[tuple[int, float]] = deque()

    _NAMES = ("end_ns", "xy", "upper", "upper_tol", "negative")

    def clear(self) -> None:
        self.start = self.stop = 0
        self.negatives = 0
        self.below_zero = 0
        self.fastest.clear()
        self.slowest.clear()

    def __len__(self) -> int:
        return self.stop - self.start

    def append(self, end_ns: int, row: tuple[float, ...]) -> None:
        """Add a row (x0, x1, x2, y, upper, v, ...) as StepModel.row gives it (v == x1 there)."""
        if self.stop == len(self.upper):
            live = {name: getattr(self, name)[self.start : self.stop].copy() for name in self._NAMES}
            kept = self.negatives, self.below_zero, self.fastest, self.slowest
            if self.start == 0:
                self._alloc(2 * len(self.upper))
            self.start, self.stop = 0, len(live["upper"])
            self.negatives, self.below_zero, self.fastest, self.slowest = kept
            for name, values in live.items():
                getattr(self, name)[: self.stop] = values
        i = self.stop
        x0, x1, x2, _, upper = row[:5]
        self.end_ns[i] = end_ns
        self.xy[i] = row[:4]
        self.upper[i] = upper
        upper_tol = upper + 1e-12 * max(1.0, abs(upper))
        self.upper_tol[i] = upper_tol
        self.below_zero += upper_tol < 0.0
        negative = x0 < 0.0 or x1 < 0.0 or x2 < 0.0
        self.negative[i] = negative
        self.negatives += negative
        self.stop += 1
        fastest, slowest = self.fastest, self.slowest
        while fastest and fastest[-1][1] <= x1:
            fastest.pop()
        fastest.append((end_ns, x1))
        while slowest and slowest[-1][1] >= x1:
            slowest.pop()
        slowest.append((end_ns, x1))

    def expire(self, min_ns: int) -> None:
        """Drop the steps that end at or before min_ns (stamps in ns, so windows of whole seconds are exact)."""
        while self.start < self.stop and self.end_ns[self.start] <= min_ns:
            self.negatives -= bool(self.negative[self.start])
            self.below_zero -= bool(self.upper_tol[self.start] < 0.0)
            self.start += 1
        fastest, slowest = self.fastest, self.slowest
        while fastest and fastest[0][0] <= min_ns:
            fastest.popleft()
        while slowest and slowest[0][0] <= min_ns:
            slowest.popleft()

    @property
    def speed_span(self) -> float:
        """max(v) - min(v) of the rows in the window, m/s (0 without rows)."""
        return self.fastest[0][1] - self.slowest[0][1] if self.fastest else 0.0

    def view(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """[x y] (n, 4), upper, upper_tol, v of the rows in the window."""
        s = slice(self.start, self.stop)
        xy = self.xy[s]
        return xy, self.upper[s], self.upper_tol[s], xy[:, 1]


class _RegimeTally:
    """The window's steps with the regimes of the valid ones: count per regime and the newest step of each."""

    def __init__(self) -> None:
        self.steps: deque[tuple[int, int | None]] = deque()  # (end_ns, regime or None: not valid), oldest first
        self.counts: dict[int, int] = {}
        self.newest: dict[int, int] = {}  # regime -> sequence number of its newest step
        self.sequence = 0

    def clear(self) -> None:
        self.steps.clear()
        self.counts.clear()
        self.newest.clear()

    def append(self, end_ns: int, regime: int | None) -> None:
        self.steps.append((end_ns, regime))
        if regime is None:
            return
        self.counts[regime] = self.counts.get(regime, 0) + 1
        self.sequence += 1
        self.newest[regime] = self.sequence

    def expire(self, min_ns: int) -> None:
        steps, counts = self.steps, self.counts
        while steps and steps[0][0] <= min_ns:
            regime = steps.popleft()[1]
            if regime is None:
                continue
            counts[regime] -= 1
            if not counts[regime]:
                del counts[regime]

    def __len__(self) -> int:
        return len(self.steps)

    def dominant(self) -> int:
        """fit.dominant_regime of the valid steps: the most frequent; a tie goes to the newest step's regime."""
        if not self.counts:
            return UNKNOWN
        top = max(self.counts.values())
        return max((r for r, count in self.counts.items() if count == top), key=self.newest.__getitem__)


class _PyWindow:
    """The window's steps (with their regimes) and rows in Python: the interface of the C kernel's Window.

    ``push`` takes each sample: the step from the last one (StepModel) goes in, the steps ending at or
    before min_ns go out.
    """

    def __init__(self, step: StepModel, capacity: int) -> None:
        self._step = step
        self._exclude_braking = step.config.exclude_braking
        self._rows = _RowBuffer(capacity)
        self._regimes = _RegimeTally()
        self._last: tuple | None = None  # (regime or -1, (t, v, f, g, tau, v_variance, limit)) of the last sample

    def push(self, end_ns: int, t: float, v: float, power_valid: bool, power_consumed: float,
             power_regenerated: float, track_force: float, tunnel_fraction: float, v_variance: float, regime: int,
             min_ns: int) -> bool:  # fmt: skip
        """A sample (ns, s, m/s, W, W, N/kg, 0..1, (m/s)^2; its regime, -1: from power); True if the step from
        the last sample to it is not valid."""
        step = self._step
        force = step.force(v, power_consumed, power_regenerated) if power_valid else math.nan
        sample = (t, v, force, track_force, tunnel_fraction, v_variance, step.limit(v))
        previous, self._last = self._last, (regime, sample)
        invalid = False
        if previous is not None:
            row = step.row(previous[1], sample)
            if row is None:
                invalid = True
                self.add(end_ns, -1, None, False)
            else:
                step_regime = previous[0] if previous[0] >= 0 else step.regime(row[7], row[6])
                self.add(end_ns, step_regime, row, not (self._exclude_braking and step_regime == BRAKING))
        self.expire(min_ns)
        return invalid

    def add(self, end_ns: int, regime: int, row: tuple | None, keep: bool) -> None:
        """A step ending at end_ns; regime -1 and row None: not a valid step; row kept for the fit if keep."""
        self._regimes.append(end_ns, None if row is None else regime)
        if row is not None and keep:
            self._rows.append(end_ns, row)

    def expire(self, min_ns: int) -> None:
        self._rows.expire(min_ns)
        self._regimes.expire(min_ns)

    def clear(self) -> None:
        self._rows.clear()
        self._regimes.clear()
        self._last = None

    @property
    def steps(self) -> int:
        return len(self._regimes)

    @property
    def rows(self) -> int:
        return len(self._rows)

    @property
    def negatives(self) -> int:
        return self._rows.negatives

    @property
    def below_zero(self) -> int:
        return self._rows.below_zero

    @property
    def speed_span(self) -> float:
        return self._rows.speed_span

    @property
    def regime(self) -> int:
        return self._regimes.dominant()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """[x y] (n, 4), upper, upper_tol, v of the rows in the window."""
        return self._rows.view()


class WindowCalibrator:
    """De Martinis & Corman's online calibration over a sliding window of ``config.window_length`` s.

    ``update`` takes each Measurement of a run with the sample's driving regime (None, UNKNOWN, a code
    outside DrivingRegime's uint8 or ``regime_source`` power: derived from the measured force and
    acceleration) and returns the fit of the window ending at that sample, or None when the sample
    carries no power (the method is inactive without it), is out of order or not finite, or no step
    has been completed yet. A new run_id starts a new window; the published values of the last
    well-posed window are kept across runs (same train). ``counts`` tallies samples and fits by
    outcome for diagnostics.

    fast: the RMSE fit from the window's QR factor (:mod:`.fast`, equal to the reference to round-off);
    False: every window by the reference solver (``fit_design``). compiled: that fit, and the window's
    steps and rows, by the C kernel where the package has it (False: in Python only; same results to
    round-off).

    Every fit also carries the window's resistance at its mean speed with its sigma (well posed whenever the train
    moves under measured power) and the run's windows pooled into r(v) with its covariance (``pooled``, a
    :class:`~.pooled.PooledResistance` from the train file's prior; kept across runs and settings, cleared by
    ``reset``): see :mod:`.pooled`.
    """

    def __init__(
        self, train: TrainSpec, config: WindowConfig | None = None, fast: bool = True, compiled: bool = True
    ) -> None:
        self.train = train
        self.fast = fast
        self.compiled = compiled
        self.counts: Counter[str] = Counter()
        self.last_fit: WindowFit | None = None
        self._origin_ns: int | None = None
        self.pooled = PooledResistance(train.davis)
        self._r2_std = math.sqrt(float(self.pooled.prior_cov[2, 2]))
        self.set_config(config or WindowConfig())

    def set_config(self, config: WindowConfig) -> None:
        """New settings: the window restarts (its steps depend on them); published values are kept."""
        self.config = config
        step = StepModel(self.train, config)
        self._step = step
        self._equations = WindowEquations()
        self._pool_last: tuple | None = None  # (regime or -1, sample as StepModel.row takes it, regenerating)
        self._fit = FastFit(self.train, config, self.compiled)
        # the C kernel's window where the fast fit runs in C, else the same in Python
        self._window = (self._fit.new_window(step) if self.fast else None) or _PyWindow(
            step, max(16, int(2 * config.window_length) + 4)
        )
        self._window_ns = round(config.window_length * 1e9)
        self._last: tuple[int, int] | None = None  # (stamp_ns, run_id) of the last sample taken

    @property
    def fit_path(self) -> str:
        """How the windows are fitted: "C kernel", "Python" (fast path without the kernel) or "reference solver"."""
        if not (self.fast and self._fit.enabled):
            return "reference solver"
        return "C kernel" if self._fit.compiled else "Python"

    @property
    def reference_windows(self) -> int:
        """Windows fitted by the reference solver (all of them with fast=False; see :mod:`.fast`)."""
        return self._fit.reference

    def reset(self) -> None:
        """Forget the window and the published values (a different train)."""
        self._clear()
        self._origin_ns = None
        self.last_fit = None
        self.pooled.clear()

    def _clear(self) -> None:
        self._window.clear()
        self._equations.clear()
        self.pooled.new_run()
        self._pool_last = None
        self._last = None

    def update(self, m: Measurement, regime: int | None = None) -> WindowFit | None:
        cfg = self.config
        if not _finite(m):
            self.counts["non_finite"] += 1
            return None
        if self._last is not None and m.run_id != self._last[1]:
            self._clear()
            self.counts["new_run"] += 1
        if self._last is not None and m.stamp_ns <= self._last[0]:
            self.counts["out_of_order"] += 1
            return None
        if self._origin_ns is None:
            self._origin_ns = m.stamp_ns
        t = (m.stamp_ns - self._origin_ns) * 1e-9
        if cfg.regime_source == "power" or regime is None or not UNKNOWN < regime < 256:
            regime = -1  # from power
        self._last = (m.stamp_ns, m.run_id)
        # the step from the last sample to this one; the window holds window_length with or without power
        if self._window.push(m.stamp_ns, t, m.v, m.power_valid, m.power_consumed, m.power_regenerated, m.track_force,
                             m.tunnel_fraction, m.v_variance, regime, m.stamp_ns - self._window_ns):  # fmt: skip
            self.counts["invalid_step"] += 1
        self._push_equation(m, t, regime)
        if not m.power_valid:
            self.counts["no_power"] += 1
            return None
        if m.v < cfg.min_speed:
            self.counts["below_min_speed"] += 1
        if not self._window.steps:  # no step in the window
            return None
        fit = self._fit_window(m.stamp_ns, m.run_id)
        self._resistance_at_speed(fit, m.v_variance)
        self.counts["ill_posed" if fit.ill_posed else "well_posed"] += 1
        if fit.dropped_constraints:
            self.counts["windows_with_dropped_constraints"] += 1
        self.last_fit = fit
        return fit

    def _push_equation(self, m: Measurement, t: float, regime: int) -> None:
        """The step to m in the window's equation (pooled.WindowEquations): the row the fit takes, in Python (one
        StepModel.row per sample), used unless braking (as the fit) or regenerating at either end."""
        step = self._step
        t, v, regenerated = float(t), float(m.v), float(m.power_regenerated)  # plain floats (numpy scalars are slow)
        force = step.force(v, float(m.power_consumed), regenerated) if m.power_valid else math.nan
        sample = (t, v, force, float(m.track_force), float(m.tunnel_fraction), float(m.v_variance), step.limit(v))
        regenerating = bool(m.power_valid) and regenerated > 0.0
        previous, self._pool_last = self._pool_last, (regime, sample, regenerating)
        if previous is not None:
            row = step.row(previous[1], sample)
            use = False
            if row is not None:
                step_regime = previous[0] if previous[0] >= 0 else step.regime(row[7], row[6])
                kept = not (self.config.exclude_braking and step_regime == BRAKING)
                use = kept and not (previous[2] or regenerating)
            self._equations.push(m.stamp_ns, t - previous[1][0], row, use)
        self._equations.expire(m.stamp_ns - self._window_ns)

    def _resistance_at_speed(self, fit: WindowFit, v_variance: float) -> None:
        """The window's resistance at its mean speed (fit.resistance_*) and the pooled r(v) (fit.pooled*)."""
        equation = self._equations.equation(float(v_variance))
        pooled = self.pooled
        if equation is not None:
            pooled.add(equation)
            value, std = equation.resistance_at_mean_speed(self.train.davis.r2, self._r2_std, pooled.scale)
            fit.resistance_speed, fit.resistance_at_speed, fit.resistance_at_speed_std = equation.mean_speed, value, std
        fit.pooled, fit.pooled_covariance, fit.pooled_windows = pooled.published

    def _fit_window(self, stamp_ns: int, run_id: int) -> WindowFit:
        context = {"stamp_ns": stamp_ns, "run_id": run_id, "previous": self.last_fit}
        if self.fast:
            return self._fit.fit_window(self._window, context)
        self._fit.reference += 1
        xy, upper, _, v = self._window.arrays()
        return fit_design(xy[:, :3], xy[:, 3], upper, v, self._window.regime, self.train, self.config, **context)


def _finite(m: Measurement) -> bool:
    """Speed, track force, tunnel fraction, speed variance and (if valid) the powers are finite."""
    if not (math.isfinite(m.v) and math.isfinite(m.track_force) and math.isfinite(m.tunnel_fraction)):
        return False
    if not math.isfinite(m.v_variance):
        return False
    return not m.power_valid or (math.isfinite(m.power_consumed) and math.isfinite(m.power_regenerated))


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
