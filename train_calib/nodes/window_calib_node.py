"""window_calib_node: /train_calib/measurement + /train_calib/regime -> /train_calib/window_resistance.

De Martinis & Corman's sliding-window calibration of A, B, C with traction power (the core's
:class:`train_calib.window.WindowCalibrator`). Each TrackMeasurement is joined by stamp with its
DrivingRegime from regime_node: a measurement is held until its regime arrives, until a regime of a
later stamp shows that it will not come, or for at most ``max_regime_wait`` samples; then it is used
with the regime from the power (their Section 5.1), as with ``regime_source`` power. The node is
active only when the measurements carry traction power (``power_valid``, paired by gnss_speed_node
from /train/traction_power): one WindowResistance per such measurement, with ``ill_posed`` set and
the last well-posed A, B, C when the window cannot separate them. Every message also carries the window's
resistance at its mean speed with its sigma (well posed whenever the train moves under measured power) and the
windows so far pooled into r(v) with its 3x3 covariance (``pooled_*``, train_calib.window.pooled). Parameter
changes restart the window (the published values and the pooled r(v) are kept).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from train_calib_msgs.msg import DrivingRegime, TrackMeasurement, WindowResistance

from .. import paths
from ..measurement import Measurement
from ..params import ParamSet
from ..regime_codes import regime_name
from ..train import load_train
from ..window import WindowCalibrator, WindowConfig, WindowFit
from .cdr import layout
from .common import TrainCalibNode
from .config import MEASUREMENT_TOPIC, REGIME_TOPIC, WINDOW_TOPIC, TrainFile
from .convert import measurement_from_msg, message_with_header, phase_from_msg, stamp_to_ns, to_cdr
from .diagnostics import WARN
from .runner import run_node

_WINDOW_LAYOUT = layout(WindowResistance)
_NAN9 = (math.nan,) * 9  # pooled_covariance of a WindowFit that carries none
DROP_REASONS = ("out_of_order", "non_finite")
"""Calibrator counts that are dropped samples (the others are outcomes, reported as values)."""


def _window_values(fit: WindowFit) -> tuple:
    """The WindowResistance fields after the header, in message order and field types (pooled_covariance a list)."""
    return (
        int(fit.run_id),
        float(fit.window_length),
        int(fit.sample_count),
        int(fit.gof_kind),
        float(fit.gof_value),
        float(fit.a),
        float(fit.b),
        float(fit.c),
        float(fit.r0),
        float(fit.r1),
        float(fit.r2),
        int(fit.regime),
        bool(fit.ill_posed),
        float(fit.speed_span),
        float(fit.resistance_speed),
        float(fit.resistance_at_speed),
        float(fit.resistance_at_speed_std),
        *(float(x) for x in fit.pooled),
        list(fit.pooled_covariance or _NAN9),  # row-major 3x3 -> 9
        int(fit.pooled_windows),
    )


def window_to_msg(fit: WindowFit, frame_id: str = "") -> WindowResistance:
    """WindowFit -> WindowResistance (same names and units; NaN before the first well-posed window)."""
    return message_with_header(WindowResistance, fit.stamp_ns, frame_id, _window_values(fit))


def window_to_cdr(fit: WindowFit, frame_id: str = "") -> bytes:
    """The serialized WindowResistance (plain CDR, what rclpy would publish for window_to_msg)."""
    *head, covariance, windows = _window_values(fit)
    return to_cdr(_WINDOW_LAYOUT, fit.stamp_ns, frame_id, (*head, *covariance, windows))


class WindowCalibNode(TrainCalibNode):
    NODE_NAME = "window_calib_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        try:
            self.train = load_train(paths.train_file(self.config(TrainFile).train_file))
            self.calibrator = WindowCalibrator(self.train, self.config(WindowConfig))
        except BaseException:
            self.destroy_node()
            raise
        self._held: deque[tuple[Measurement, str]] = deque()  # (measurement, frame_id) awaiting the regime
        # (run_id, stamp_ns) -> regime, for held and not yet seen measurements; keyed and ordered by run first, as
        # a new run may restart the clock (a stamp of run k + 1 can be older than one of run k)
        self._regimes: dict[tuple[int, int], int] = {}
        self._newest_regime: tuple[int, int] = (-1, -1)
        self._measurements = 0
        self._with_power = 0
        self._regime_from_power = 0
        self._last: WindowFit | None = None
        self.output(WindowResistance, WINDOW_TOPIC)
        self.chain_input(TrackMeasurement, MEASUREMENT_TOPIC, self._on_measurement)
        self.chain_input(DrivingRegime, REGIME_TOPIC, self._on_regime)
        cfg = self.config(WindowConfig)
        self.get_logger().info(
            f"train {self.train.name}: gamma m {self.train.effective_mass_kg / 1000:.1f} t, eta "
            f"{self.train.transmission_efficiency:g}; window {cfg.window_length:g} s, GoF {cfg.gof}, "
            f"regime from {cfg.regime_source}; fit: {self.calibrator.fit_path}"
        )

    # -- inputs -----------------------------------------------------------------------------------
    def _on_measurement(self, msg: TrackMeasurement) -> None:
        m = measurement_from_msg(msg)
        self._measurements += 1
        self._with_power += bool(m.power_valid)
        self._held.append((m, msg.header.frame_id))
        self._release()

    def _on_regime(self, msg: DrivingRegime) -> None:
        key = (int(msg.run_id), stamp_to_ns(msg.header.stamp))
        self._regimes[key] = phase_from_msg(msg)  # the paper's phase (the pipeline's too)
        self._newest_regime = max(self._newest_regime, key)
        self._release()

    def _release(self, everything: bool = False) -> None:
        """Feed held measurements, oldest first, as soon as their regime is known or cannot come."""
        cfg = self.config(WindowConfig)
        while self._held:
            m, frame_id = self._held[0]
            key = (m.run_id, m.stamp_ns)
            regime = self._regimes.pop(key, None)
            if regime is None and cfg.regime_source == "regime_topic":
                # regimes come in stamp order: one of a later stamp means this one will not come; with no
                # regime at all after max_regime_wait measurements, regime_node is not running
                expected = self._newest_regime[0] >= 0 or self._measurements <= cfg.max_regime_wait
                waiting = expected and key > self._newest_regime and len(self._held) <= cfg.max_regime_wait
                if waiting and not everything:
                    return
                self._regime_from_power += 1
            self._held.popleft()
            fit = self.calibrator.update(m, regime)
            if fit is not None:
                self._last = fit
                self.publish(WINDOW_TOPIC, window_to_cdr(fit, frame_id))
        # regimes of measurements never seen (dropped upstream) must not accumulate
        if len(self._regimes) > 4 * max(cfg.max_regime_wait, 1) + 100:
            oldest = self._held[0][0] if self._held else None
            oldest_held = (oldest.run_id, oldest.stamp_ns) if oldest is not None else self._newest_regime
            self._regimes = {k: r for k, r in self._regimes.items() if k >= oldest_held}

    # -- node conventions -------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        return len(self._held)

    def end_of_input(self) -> None:
        self._release(everything=True)

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if WindowConfig in changed:
            self._release(everything=True)
            self.calibrator.set_config(self.config(WindowConfig))

    def refresh_counters(self) -> None:
        counts = self.calibrator.counts
        self.set_drops(MEASUREMENT_TOPIC, {reason: counts[reason] for reason in DROP_REASONS if counts[reason]})

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        counts = self.calibrator.counts
        out: list[tuple[str, Any]] = [
            ("measurements with traction power", self._with_power),
            ("measurements without power (inactive)", counts["no_power"]),
            ("windows well posed", counts["well_posed"]),
            ("windows ill posed", counts["ill_posed"]),
            ("windows with eq. 6/7 rows dropped", counts["windows_with_dropped_constraints"]),
            ("steps not usable (speed, gap, power)", counts["invalid_step"]),
            ("regime from power (no /train_calib/regime in time)", self._regime_from_power),
            ("held for the regime", len(self._held)),
            ("window fit", self.calibrator.fit_path),
            ("windows by the reference solver", self.calibrator.reference_windows),
        ]
        f = self._last
        if f is not None:
            out += [
                ("run_id", f.run_id),
                ("A (N)", _g(f.a)),
                ("B (N/(m/s))", _g(f.b)),
                ("C (N/(m/s)^2)", _g(f.c)),
                ("r0 r1 r2 (N/kg)", f"{_g(f.r0)} {_g(f.r1)} {_g(f.r2)}"),
                ("last window steps", f.sample_count),
                ("last window regime", regime_name(f.regime)),
                ("last window GoF (N)", _g(f.gof_value)),
                ("last window ill posed", f.reason or "no"),
                (
                    "last window r(mean speed) (N/kg)",
                    f"{_g(f.resistance_at_speed)} +- {_g(f.resistance_at_speed_std)} at {_g(f.resistance_speed)} m/s",
                ),
                ("pooled r0 r1 r2 (N/kg)", " ".join(_g(x) for x in f.pooled)),
                ("pooled windows", f.pooled_windows),
            ]
        return out

    def diagnostic_problems(self) -> list[tuple[int, str]]:
        if self._measurements and not self._with_power:
            return [(WARN, f"inactive: none of {self._measurements} measurements carries traction power")]
        return []


def _g(value: float) -> str:
    return "nan" if math.isnan(value) else f"{value:.6g}"


def main(args: list[str] | None = None) -> int:
    return run_node(WindowCalibNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
