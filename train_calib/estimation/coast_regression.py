"""Running resistance from the coasting stretches of a run: detection from the data, Bayesian regression.

Without traction power only coasting (u = 0) tells r: there a = -(r(v) + g(s)). The method (docs/estimator.md,
"Coast regression"):

1. **Speed noise** sigma_v from the data: the robust spread of second differences of the measured speed (MAD),
   at least the resolution's q / sqrt(12).
2. **Local slope** a_i of the measured speeds, a centred linear fit over a window W chosen so that its standard
   error is ``coast_slope_precision`` of r (longer with noisier or sparser speeds), at least
   ``coast_window_min`` and ``coast_window_samples`` sample periods.
3. **Coasting candidates**: the apparent resistance -(a_i + g_i) lies within ``coast_ratio_min`` ..
   ``coast_ratio_max`` of the train file's r(v) (wide: a prior 10-30 % off must not select the samples that agree
   with it), and |a_i| is at least ``coast_hold_sigmas`` standard errors from 0 (a held speed, a = 0, is a hold
   or says nothing). Traction and braking give an apparent r far outside the band.
4. **Stretches**: runs of candidate steps, trimmed by W/2 at each end (the centred window smears a phase change
   over W/2), at least ``coast_min_duration``.
5. **Equations**, one per sample of a stretch, the motion equation integrated from the stretch's start (no
   differentiation of the speed): v_i + G_i = c - r0 (t_i - t_0) - r1 V1_i - r2 V2_i + n_i, with G, V1, V2 the
   trapezoidal integrals of g, v and v^2 (1 + f_tun tunnel) since t_0, c the unknown speed at t_0 (eliminated by
   centring the equations over the stretch) and n_i the speed noise, independent with variance sigma_v^2. Every
   sample counts (a coast's deceleration from N samples has the standard error of a straight-line fit,
   sigma_v sqrt(12 / N) / T, not the sqrt(2) sigma_v / T of its two end points). An error common to a coast, a
   constant extra deceleration with std ``coast_stretch_std`` of r (grade and curve errors, a light traction or
   brake inside it), adds b^2 tau tau^T (tau the centred time): a coast counts as one piece of evidence, not as its
   number of samples (stretches less than 2 W apart are one coast).
6. **Bayesian regression** from the prior N(train file, P0), P0 = s_c^2 r r^T + diag((s_j r_j)^2): a common scale
   (the whole curve 10-30 % off, ``prior_scale_std``) and per-coefficient jitter (``prior_coefficient_std``).
   Where no stretch is found the answer is the prior with the prior's covariance.

:func:`fit_coasts` is the whole-run (offline) estimate; :class:`CoastRegression` the causal one used by the UKF
(``resistance_learning: coast_regression``): it re-detects on the samples since the last completed stretch and
adds a stretch once it is over (the step after it decided), so the published r moves at the end of each coast.
Knowledge carries over across stops (run_id changes) within one recording.

Where each step lives: steps 1-4 (the time form's detection) in :mod:`coast_detection`, the energy form's
detection and equations at 10 s in :mod:`coast_energy`, step 5 here (:func:`stretch_equations`), step 6 in
:mod:`coast_posterior`; the whole-run fit and the causal class here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..train import Davis, TrainSpec
from .coast_detection import (
    bounds_of,
    candidate_steps,
    detect,
    median,
    monotonic_parts,
    noise_from_differences,
    sample_period,
    slope_window,
    speed_noise,
)
from .coast_energy import (
    energy_bounds,
    energy_equations,
    energy_sigma_v,
    neighbour_limits,
    step_grade_error,
    uses_energy_form,
)
from .coast_posterior import (
    add_coast,
    nonnegative,
    posterior,
    prior_covariance,
    prior_information,
    resistance_and_sigma,
    solve_information,
)
from .coast_types import (
    POWER_DRIVE,
    POWER_NONE,
    POWER_UNKNOWN,
    CoastSettings,
    RunArrays,
    Stretch,
    davis_value,
    power_states,
)

try:
    from . import _ukf_kernel  # the C kernel of CoastRegression.push (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - built without a compiler: the Python path
    _ukf_kernel = None


@dataclass
class CoastFit:
    """The regression's answer: r = (r0, r1, r2) and its 3x3 covariance, with what it used."""

    r: np.ndarray
    covariance: np.ndarray
    stretches: list[Stretch] = field(default_factory=list)
    speed_noise: float = float("nan")  # m/s
    window: float = float("nan")  # s

    @property
    def davis(self) -> Davis:
        return Davis(*(float(x) for x in self.r))

    @property
    def r0(self) -> float:
        return float(self.r[0])

    @property
    def r1(self) -> float:
        return float(self.r[1])

    @property
    def r2(self) -> float:
        return float(self.r[2])

    @property
    def coasting_time(self) -> float:
        """Seconds of coasting used."""
        return float(sum(s.t_end - s.t_start for s in self.stretches))

    def resistance(self, v: float) -> tuple[float, float]:
        """(r(v), its std) in N/kg at speed v (m/s)."""
        return resistance_and_sigma(self.r, self.covariance, v)


def _cumulative_trapezoid(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Integral of y over t from t[0] to each t[i] (trapezoid), same length as t."""
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(t))
    return out


def stretch_equations(
    arr: RunArrays, k0: int, k1: int, settings: CoastSettings, prior: np.ndarray, sigma_v: float, tunnel_factor: float
) -> Stretch:
    """The centred integrated equations of samples k0..k1 (module docstring, step 5)."""
    t, v = arr.t[k0 : k1 + 1], arr.v[k0 : k1 + 1]
    g, tun = arr.g[k0 : k1 + 1], arr.tunnel[k0 : k1 + 1]
    phi = np.column_stack(
        (t - t[0], _cumulative_trapezoid(v, t), _cumulative_trapezoid(v * v * (1.0 + tunnel_factor * tun), t))
    )
    y = v + _cumulative_trapezoid(g, t)
    tau = t - np.mean(t)
    bias = settings.coast_stretch_std * float(davis_value(prior, float(np.mean(v))))
    return Stretch(
        float(t[0]), float(t[-1]), float(np.min(v)), float(np.max(v)),
        -(phi - phi.mean(axis=0)), y - np.mean(y), tau, sigma_v * sigma_v, bias, int(arr.run[k0]),
    )  # fmt: skip


def assign_group(stretch: Stretch, previous: Stretch | None, merge_gap: float) -> None:
    """The stretch belongs to the previous one's coast when it starts within merge_gap (s) of its end in the same
    run (a short gap in the candidates inside one coast), else it opens a new group."""
    if previous is None:
        stretch.group = 0
    elif stretch.run == previous.run and stretch.t_start - previous.t_end <= merge_gap:
        stretch.group = previous.group
    else:
        stretch.group = previous.group + 1


def fit_coasts(
    arr: RunArrays, train: TrainSpec, settings: CoastSettings | None = None, prior: Davis | None = None
) -> CoastFit:
    """Whole-run estimate: every coasting stretch of the run (offline, non-causal detection)."""
    cfg = settings if settings is not None else CoastSettings()
    r_prior = np.asarray((prior if prior is not None else train.davis).as_tuple(), dtype=float)
    P0 = prior_covariance(r_prior, cfg.prior_scale_std, cfg.prior_coefficient_std)
    finite = np.isfinite(arr.t) & np.isfinite(arr.v) & np.isfinite(arr.g)
    if not np.all(finite):  # as CoastRegression.push: a sample without t, v or g is no measurement
        arr = arr.part(finite)
    if arr.t.size < 3:
        return CoastFit(r_prior, P0)
    sv = speed_noise(arr.v)
    window = math.nan
    stretches: list[Stretch] = []
    for part in monotonic_parts(arr):  # a clock reset starts the time base anew: each part on its own
        period = sample_period(part.t)
        if uses_energy_form(
            part, cfg, period, step_grade_error(part, r_prior, cfg.coast_min_speed)
        ):  # sparse samples: coast_energy
            sv_e = energy_sigma_v(part, sv)
            bounds, _ = energy_bounds(part, cfg, r_prior, sv_e, period)
            window = cfg.coast_energy_window * period
            spans = [(k0, k1) for k0, k1, _, _ in bounds]
            equations = [
                energy_equations(part, k0, k1, cfg, r_prior, sv_e, train.tunnel_factor, period, lo, hi)
                for (k0, k1), (lo, hi) in zip(spans, neighbour_limits(spans, 0, part.t.size - 1))
            ]
        else:
            bounds, _, window = detect(part, cfg, r_prior, sv)
            equations = [
                stretch_equations(part, k0, k1, cfg, r_prior, sv, train.tunnel_factor) for k0, k1, _, _ in bounds
            ]
        for st in equations:
            assign_group(st, stretches[-1] if stretches else None, 2.0 * window)
            stretches.append(st)
    r, cov = posterior(r_prior, P0, stretches)
    return CoastFit(nonnegative(r, cov), cov, stretches, sv, window)


class CoastRegression:
    """Causal coast regression: ``push`` each measurement; r and its covariance move when a stretch is over.

    Every ``REFRESH`` s (and ``REFRESH_PERIODS`` periods, and at the first slow sample after moving) the detection
    of :func:`fit_coasts` runs over the samples kept. A stretch is used once it is over: the step after its last
    candidate step decided (its slope window complete), its trimmed end W/2 before that. Kept
    are the samples from W before the first candidate run that is not over yet, or before the horizon (a pass
    costs the length of the open coast, not of the recording). sigma_v comes from every moving sample seen (a
    bounded sample of second and third differences); W from sigma_v and the highest speed so far.
    """

    REFRESH = 20.0  # s between detections ...
    REFRESH_PERIODS = 6  # ... and at least this many sample periods (10 s sampling: every minute)
    NOISE_SAMPLES = 4000  # second differences kept for the speed-noise estimate

    def __init__(self, train: TrainSpec, settings: CoastSettings, prior: Davis | None = None) -> None:
        self._train = train
        self.settings = settings
        self.tunnel_factor = train.tunnel_factor
        self.prior = np.asarray((prior if prior is not None else train.davis).as_tuple(), dtype=float)
        self.P0 = prior_covariance(self.prior, settings.prior_scale_std, settings.prior_coefficient_std)
        self.r = self.prior.copy()
        self.covariance = self.P0.copy()
        self.stretches: list[Stretch] = []
        # the information of the prior and of every coast that is over (a new stretch can only join the last one):
        # each update adds the open coast to it instead of summing every coast again (a recording of hours)
        self._closed_info = prior_information(self.prior, self.P0)
        self._closed_count = 0  # stretches whose coast is in _closed_info
        self._t: list[float] = []
        self._v: list[float] = []
        self._g: list[float] = []
        self._tun: list[float] = []
        self._run: list[int] = []
        self._power: list[int] = []
        self._s: list[float] = []  # m
        self._gamma: list[float] = []  # J/kg, the track force's integral (NaN: unknown)
        self._s_var: list[float] = []  # m^2
        self._v_var: list[float] = []  # (m/s)^2, the sensor's stated variance
        self._d2: deque[float] = deque(maxlen=self.NOISE_SAMPLES)  # second differences of the moving speeds
        self._d3: deque[float] = deque(maxlen=self.NOISE_SAMPLES)  # third differences (noise estimate)
        self._prior_floats = tuple(float(x) for x in self.prior)
        self._grade, self._grade_at, self._grade_seen = math.nan, 0, 0
        self._grade_errors: deque[float] = deque(maxlen=self.NOISE_SAMPLES)  # coast_energy.step_grade_error's terms
        self._quantum = math.inf
        self._v_max = 0.0
        self._last_detect = -math.inf
        self.window = math.nan  # s, the slope window of the latest detection
        self._used_until = -math.inf  # t of the last sample used in a stretch (s)
        self._d2_seen = 0
        self._sv, self._sv_at = math.nan, 0
        self._period = math.nan  # s, the latest sample interval
        self._refresh_wait = float(self.REFRESH)  # s between detections: max(REFRESH, REFRESH_PERIODS * _period)
        self._v_min = settings.coast_min_speed  # m/s
        self._moved = False  # a moving sample since the last detection
        self._moving_before = False  # the previous sample was moving
        self._open = False  # the last detection left a candidate run open

    def reset(self) -> None:
        """Back to the prior (forget every stretch)."""
        self.__init__(self._train, self.settings, Davis(*self.prior))

    def grade_error(self) -> float:
        """coast_energy.step_grade_error over the moving steps seen (the latest NOISE_SAMPLES)."""
        errors = self._grade_errors
        return median(np.fromiter(errors, float, len(errors))) if errors else 0.0

    def _grade_error_cached(self) -> float:
        """grade_error, recomputed after every 16 new steps (the detection asks at every pass)."""
        if self._grade_seen - self._grade_at >= 16 or not math.isfinite(self._grade):
            self._grade = self.grade_error()
            self._grade_at = self._grade_seen
        return self._grade

    def sigma_v(self) -> float:
        """Current speed-noise estimate (m/s); recomputed after every 64 new second differences."""
        if self._d2_seen - self._sv_at >= 64 or not math.isfinite(self._sv):
            self._sv, self._sv_at = self._sigma_v(), self._d2_seen
        return self._sv

    def _sigma_v(self) -> float:
        q = self._quantum if math.isfinite(self._quantum) else 0.0
        if not (self._d2 or q):
            return 0.08
        d2, d3 = self._d2, self._d3
        return noise_from_differences(np.fromiter(d2, float, len(d2)), np.fromiter(d3, float, len(d3)), q)

    def push(
        self,
        t: float,
        v: float,
        g: float,
        tunnel: float,
        run_id: int,
        power: int = POWER_UNKNOWN,
        s: float = math.nan,
        gamma: float = math.nan,
        s_var: float = 0.0,
        v_var: float = math.nan,
    ) -> bool:
        """One measurement (t in s, v m/s, g N/kg, power a POWER_* state; s in m, gamma = the track force's integral
        in J/kg, s_var m^2 and v_var (m/s)^2 for the energy form); True when r or its covariance changed.

        The bookkeeping up to the detection in C where the package was built with a compiler
        (``_ukf_kernel.coast_push``: :meth:`push_python`'s steps, the same floats; a stamp not after the last one
        goes to :meth:`push_python`), else :meth:`push_python`."""
        if _ukf_kernel is not None:
            code = _ukf_kernel.coast_push(self, t, v, g, tunnel, run_id, power, s, gamma, s_var, v_var)
            if code != 2:
                return code == 1 and self._detect()
        return self.push_python(t, v, g, tunnel, run_id, power, s, gamma, s_var, v_var)

    def push_python(
        self,
        t: float,
        v: float,
        g: float,
        tunnel: float,
        run_id: int,
        power: int = POWER_UNKNOWN,
        s: float = math.nan,
        gamma: float = math.nan,
        s_var: float = 0.0,
        v_var: float = math.nan,
    ) -> bool:
        """:meth:`push` in Python (the C kernel's reference)."""
        if not (math.isfinite(t) and math.isfinite(v) and math.isfinite(g)):
            return False
        ts, vs, runs = self._t, self._v, self._run
        n = len(ts)
        if n and t <= ts[-1]:
            if run_id == runs[-1]:
                return False  # an older or repeated stamp within the run: not a measurement to use
            self._keep_from(n)  # a new run on a new time base (clock reset): what was learnt stays
            self._used_until = self._last_detect = -math.inf
            n = 0
        v_min = self._v_min
        if n:  # the noise and grade-error terms of the step from the previous sample
            v1 = vs[-1]
            same_run = runs[-1] == run_id
            dv = abs(v - v1)
            if dv > 1e-4:
                self._quantum = min(self._quantum, dv)
            if n >= 2 and v1 > 5.0 and same_run and run_id == runs[-2]:
                v2 = vs[-2]
                self._d2.append(v - 2.0 * v1 + v2)
                self._d2_seen += 1
                if n >= 3 and runs[-3] == run_id and v2 > 5.0:
                    self._d3.append(v - 3.0 * v1 + 3.0 * v2 - vs[-3])
            gamma1 = self._gamma[-1]
            if same_run and math.isfinite(gamma) and math.isfinite(gamma1):
                ds = s - self._s[-1]
                if ds > 1.0 and v >= v_min and v1 >= v_min:
                    v_mid = 0.5 * (v + v1)
                    r0, r1, r2 = self._prior_floats
                    exact = (gamma - gamma1) / ds
                    self._grade_errors.append(
                        abs(exact - 0.5 * (g + self._g[-1])) / max(r0 + (r1 + r2 * v_mid) * v_mid, 1e-6)
                    )
                    self._grade_seen += 1
            self._period = t - ts[-1]
            self._refresh_wait = max(self.REFRESH, self.REFRESH_PERIODS * self._period)
        ts.append(t)
        vs.append(v)
        self._g.append(g)
        self._tun.append(tunnel if math.isfinite(tunnel) else 0.0)
        runs.append(int(run_id))
        self._power.append(int(power))
        self._s.append(s)
        self._gamma.append(gamma)
        self._s_var.append(s_var if math.isfinite(s_var) else 0.0)
        self._v_var.append(v_var)
        if v > self._v_max:
            self._v_max = v
        moving = v >= v_min
        stopped = self._moving_before and not moving  # the first slow sample after moving: a coast before is over
        self._moving_before = moving
        if moving:
            self._moved = True
        if not stopped and t - self._last_detect < self._refresh_wait:
            return False
        self._last_detect = t
        if not self._moved and not self._open:  # standing since the last detection: nothing can have changed
            return False
        self._moved = False
        return self._detect()

    def _detect(self) -> bool:
        cfg = self.settings
        powered = self._power.count(POWER_UNKNOWN) < len(self._power)
        arr = RunArrays(
            np.asarray(self._t),
            np.asarray(self._v),
            np.asarray(self._g),
            np.asarray(self._tun),
            np.asarray(self._run, dtype=np.int64),
            np.asarray(self._power, dtype=np.int8) if powered else None,
        )
        if arr.t.size < 3:
            return False
        sv = self.sigma_v()
        period = sample_period(arr.t)
        if period >= cfg.coast_energy_period:  # the energy form's columns only where it may apply
            arr.s, arr.gamma = np.asarray(self._s), np.asarray(self._gamma)
            if uses_energy_form(arr, cfg, period, self._grade_error_cached()):
                arr.s_var, arr.v_var = np.asarray(self._s_var), np.asarray(self._v_var)
                return self._detect_energy(arr, sv, period)
        self.window = window = slope_window(cfg, sv, period, self.prior, self._v_max)
        by_speed, by_power = candidate_steps(arr, cfg, self.prior, sv, window, period)
        step = by_speed | by_power
        trim = 0.5 * window
        bounds = bounds_of(arr, by_speed, by_power, cfg, window, period)
        t_last = float(arr.t[-1])
        horizon = t_last - 0.5 * window - trim  # older samples serve no stretch still open
        decided = t_last - 0.5 * window - period
        pieces = self._new_pieces(arr, bounds, decided, max(cfg.coast_min_duration, 3.0 * period))
        make = [stretch_equations(arr, k0, k1, cfg, self.prior, sv, self.tunnel_factor) for k0, k1 in pieces]
        return self._add(arr, pieces, make, step, window, horizon)

    def _detect_energy(self, arr: RunArrays, sv: float, period: float) -> bool:
        """_detect in the energy form (sparse samples, :mod:`coast_energy`). A stretch is over once no window that
        could still hold the sample after it can pass: each is complete, or holds a sample where the train is too
        slow, a new run or a gap (a coast before a stop is over at the stop). Kept are the samples from W before
        the first stretch not over yet, or before the horizon."""
        cfg = self.settings
        sv_e = energy_sigma_v(arr, sv)
        bounds, flag = energy_bounds(arr, cfg, self.prior, sv_e, period)
        m = int(cfg.coast_energy_window)
        self.window = window = m * period
        n = arr.t.size
        broken = arr.v < cfg.coast_min_speed  # a window holding such a sample cannot pass
        broken[1:] |= (arr.run[1:] != arr.run[:-1]) | (np.diff(arr.t) > min(cfg.max_gap, 2.5 * period))
        first_used = int(np.searchsorted(arr.t, self._used_until, side="right"))
        min_duration = max(cfg.coast_min_duration, 3.0 * period)
        pieces, waiting = [], []
        for k0, k1, _, _ in bounds:
            k0 = max(k0, first_used)  # a stretch grown back into samples already used starts after them
            if k1 - k0 < 2 or arr.t[k1] - arr.t[k0] < min_duration:
                continue
            over = k1 + m <= n - 1 or bool(np.any(broken[k1 + 1 : k1 + m + 1]))
            (pieces if over and k1 + 1 < n else waiting).append((k0, k1))
        make = [  # outer neighbours: not used yet, not in another piece
            energy_equations(arr, k0, k1, cfg, self.prior, sv_e, self.tunnel_factor, period, lo, hi)
            for (k0, k1), (lo, hi) in zip(pieces, neighbour_limits(pieces, first_used, n - 1))
        ]
        horizon = arr.t[-1] - m * period
        if waiting:
            horizon = min(horizon, float(arr.t[waiting[0][0]]))
        return self._add(arr, pieces, make, flag, window, horizon)

    def _add(
        self,
        arr: RunArrays,
        pieces: list[tuple[int, int]],
        stretches: list[Stretch],
        step: np.ndarray,
        window: float,
        horizon: float,
    ) -> bool:
        """Take the new stretches into the posterior; drop the samples no open stretch needs (those from W before
        the first candidate run not over yet, or before the horizon)."""
        changed = False
        if pieces:
            for st in stretches:
                assign_group(st, self.stretches[-1] if self.stretches else None, 2.0 * window)
                self.stretches.append(st)
            r, cov = self._posterior()
            self.r, self.covariance = nonnegative(r, cov), cov
            self._used_until = float(arr.t[pieces[-1][1]])
            changed = True
        keep_t = horizon - window
        idx = step.nonzero()[0]
        late = idx[arr.t[idx] > horizon] if idx.size else idx
        self._open = bool(late.size)
        if late.size:
            # the candidate run holding late[0] starts after the last sample before it that is not a candidate
            before = (~step[: int(late[0])]).nonzero()[0]
            i = int(before[-1]) + 1 if before.size else 0
            keep_t = min(keep_t, float(arr.t[i - 1]) - window if i > 0 else float(arr.t[0]))
        self._keep_from(int(arr.t.searchsorted(keep_t)))
        return changed

    def _posterior(self) -> tuple[np.ndarray, np.ndarray]:
        """posterior() of every stretch so far: the closed coasts' cached information plus the last coast's (the
        same additions in the same order, so the same numbers)."""
        open_group = self.stretches[-1].group
        first_open = self._closed_count
        while self.stretches[first_open].group != open_group:
            end = first_open
            while self.stretches[end].group == self.stretches[first_open].group:
                end += 1
            self._closed_info = add_coast(self._closed_info, self.stretches[first_open:end])
            first_open = end
        self._closed_count = first_open
        return solve_information(add_coast(self._closed_info, self.stretches[first_open:]))

    def _new_pieces(
        self, arr: RunArrays, bounds: list[tuple[int, int, int, int]], decided: float, min_duration: float
    ) -> list[tuple[int, int]]:
        """Sample ranges to add now: each stretch that is over (the step after its last candidate step is decided:
        before ``decided``, its slope window complete) and not used yet. A long coast is used when it is over:
        taking it in pieces while it lasts was tried and cost accuracy (tune half 1.9 -> 4.3 % median: the
        pieces cut the chunks elsewhere, and their ends are decided on shorter evidence)."""
        out = []
        for k0, k1, _, j in bounds:
            over = j + 1 < arr.t.size and arr.t[j + 1] <= decided
            if over and arr.t[k0] > self._used_until and arr.t[k1] - arr.t[k0] >= min_duration:
                out.append((k0, k1))
        return out

    def _keep_from(self, k: int) -> None:
        if k <= 0:
            return
        for buf in (self._t, self._v, self._g, self._tun, self._run, self._power, self._s, self._gamma, self._s_var,
                    self._v_var):  # fmt: skip
            del buf[:k]


__all__ = [
    "POWER_DRIVE",
    "POWER_NONE",
    "POWER_UNKNOWN",
    "CoastFit",
    "CoastRegression",
    "CoastSettings",
    "RunArrays",
    "Stretch",
    "davis_value",
    "fit_coasts",
    "power_states",
    "prior_covariance",
    "resistance_and_sigma",
    "speed_noise",
]
