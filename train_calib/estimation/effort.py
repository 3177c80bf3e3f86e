"""Applied effort u = f_t - f_b (N/kg of effective mass) and the observed acceleration.

* Observed acceleration: slope of a causal least-squares line through the measured speeds of the last
  ``window`` seconds (+2 % for stamp jitter; at least the last two samples). At 10 s sampling with a 10 s window this is
  the paper's two-point difference; at 1 Hz it averages the 1 km/h quantisation over ~11 samples.
* Computed effort (Cunillera Section 3, 4.2): u = dv/dt + r_hat(v) + g(s) with the latest estimate.
* Known traction effort from pantograph power (De Martinis eq. 3):
  f_t = eta (P_consumed - P_aux) / (v gamma m).
"""

from __future__ import annotations

from collections import deque

from ..train import TrainSpec

try:
    from . import _ukf_kernel  # SpeedSlope.push in C (setup.py builds it where a C compiler is found)
except ImportError:  # pragma: no cover - built without a compiler: the Python push
    _ukf_kernel = None


class SpeedSlope:
    """Causal linear-fit slope of measured speed over a time window (m/s^2), O(1) per sample.

    Running sums of (t - t_ref), v and their products over the samples in the window; they are
    recomputed from the samples every ``_REFRESH`` pushes so rounding cannot accumulate.
    """

    _REFRESH = 256
    __slots__ = ("_count", "_points", "_st", "_stt", "_stv", "_sv", "_svv", "_t_ref", "slope", "window")

    def __init__(self, window_s: float) -> None:
        self.window = float(window_s)
        self._points: deque[tuple[float, float]] = deque()
        self.reset()

    def reset(self) -> None:
        self._points.clear()
        self.slope = 0.0
        self._t_ref = 0.0
        self._st = self._sv = self._stt = self._stv = self._svv = 0.0
        self._count = 0

    @property
    def span(self) -> float:
        """Time covered by the samples in the window, s."""
        pts = self._points
        return pts[-1][0] - pts[0][0] if len(pts) > 1 else 0.0

    def push(self, t: float, v: float) -> float:
        """Add the sample (t in s, v in m/s) and return the slope over the window (0 with one sample): in C where the
        package was built with a compiler (``_ukf_kernel.slope_push``, :meth:`push_python`'s operations), else
        :meth:`push_python`."""
        if _ukf_kernel is not None:
            return _ukf_kernel.slope_push(self, t, v)
        return self.push_python(t, v)

    def push_python(self, t: float, v: float) -> float:
        """:meth:`push` in Python (the C kernel's reference)."""
        pts = self._points
        if not pts:
            self._t_ref = t
        pts.append((t, v))
        t_ref = self._t_ref
        d = t - t_ref
        # the running sums in locals, stored once (the same additions in the same order)
        st, sv, stt, stv, svv = self._st + d, self._sv + v, self._stt + d * d, self._stv + d * v, self._svv + v * v
        limit = t - 1.02 * self.window - 1e-6  # 2 % tolerance for stamp jitter
        while len(pts) > 2 and pts[0][0] < limit:
            t0, v0 = pts.popleft()
            d = t0 - t_ref
            st -= d
            sv -= v0
            stt -= d * d
            stv -= d * v0
            svv -= v0 * v0
        self._st, self._sv, self._stt, self._stv, self._svv = st, sv, stt, stv, svv
        self._count += 1
        if self._count >= self._REFRESH:
            self._refresh()
        self.slope = slope = self._fit()
        return slope

    def _refresh(self) -> None:
        self._count = 0
        pts = self._points
        self._t_ref = t_ref = pts[0][0]
        st = sv = stt = stv = svv = 0.0
        for ti, vi in pts:
            d = ti - t_ref
            st += d
            sv += vi
            stt += d * d
            stv += d * vi
            svv += vi * vi
        self._st, self._sv, self._stt, self._stv, self._svv = st, sv, stt, stv, svv

    def residual_std(self) -> float:
        """Standard deviation of the speeds about the fitted line (n - 2 dof), m/s; 0 with fewer than 3 samples."""
        n = len(self._points)
        if n < 3:
            return 0.0
        sxx = self._stt - self._st * self._st / n
        syy = self._svv - self._sv * self._sv / n
        sxy = self._stv - self._st * self._sv / n
        ss = syy - (sxy * sxy / sxx if sxx > 0.0 else 0.0)
        return (max(ss, 0.0) / (n - 2)) ** 0.5

    def _fit(self) -> float:
        pts = self._points
        n = len(pts)
        if n < 2:
            return 0.0
        if n == 2:
            (t0, v0), (t1, v1) = pts
            return (v1 - v0) / (t1 - t0) if t1 > t0 else 0.0
        sxx = self._stt - self._st * self._st / n
        if not sxx > 0.0:
            return 0.0
        return (self._stv - self._st * self._sv / n) / sxx


class PowerEffort:
    """Tractive effort per unit effective mass from pantograph power (W -> N/kg)."""

    __slots__ = ("aux_w", "eta_per_mass")

    def __init__(self, train: TrainSpec) -> None:
        self.eta_per_mass = train.transmission_efficiency / train.effective_mass_kg
        self.aux_w = train.auxiliary_power_kw * 1e3

    def wheel_power(self, power_consumed_w: float) -> float:
        """Wheel power per unit effective mass, W/kg: eta (P - P_aux) / (gamma m)."""
        return self.eta_per_mass * (power_consumed_w - self.aux_w)
