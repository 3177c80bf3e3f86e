"""regime_node: /train_calib/resistance -> /train_calib/regime (DrivingRegime), one per estimate.

The core's :class:`~train_calib.estimation.RegimeClassifier` (Cunillera et al. 2022, Section 3.2; docs/estimator.md,
"Regimes") on each estimate's effort, acceleration and filtered speed, with its ``effort_known`` and the force the
effort works against, ``resistance + track_force`` (:func:`train_calib.pipeline.classify_estimate`, the offline
pipeline's call too). Standing (slower than ``standstill_speed``) is UNKNOWN.

Each message carries two labels: ``regime``, what the train does at that sample (``method: imm``, the default:
an interacting multiple-model filter on the measured speeds and stamps; traction/coast cycles are traction and
coasting), and ``phase``, the paper's phase (the ``hmm`` below; with ``hmm`` or ``rule`` the regime itself), which
feature_node and window_calib_node use. ``hmm`` and ``imm`` are causal and stateful: their belief over the
regimes is carried from sample to sample (restarted by a standstill). ``method: rule`` is the paper's stateless
per-sample rule. A parameter change at run time takes effect at once by building a new classifier: this restarts
the belief (the next sample is classified as the first of a departure). ``lag_samples: 1`` publishes each sample
when the next estimate has come, its phase revised with it (:class:`train_calib.pipeline.RegimeStream`; the
message keeps the sample's own stamp and frame_id).

The imm also weighs each sample by the state of its traction power where measured (traction drawn, regenerated,
neither: :func:`train_calib.estimation.regime_model.power_state`, with the train file's efficiency, mass and
auxiliary power) and takes the mean track force over the step from the measurements' s and
``track_force_integral``, both from the sample's /train_calib/measurement: an estimate is held until the
measurement of its stamp has come (it comes first: ukf_node publishes the estimate after it), until a later one has
come (dropped), or for at most ``MEASUREMENT_WAIT`` estimates (no measurement topic: the regimes from the speeds
alone), as the offline pipeline pairs them (:class:`train_calib.pipeline.Pipeline`).
"""

from __future__ import annotations

from collections import Counter, deque
from typing import Any

from train_calib_msgs.msg import DrivingRegime, ResistanceEstimate, TrackMeasurement

from .. import paths
from ..estimation import REGIME_NAMES, RegimeClassifier, RegimeConfig
from ..estimation.effort import PowerEffort
from ..estimation.regime_model import power_state
from ..params import ParamSet
from ..pipeline import RegimeStream
from ..train import load_train
from .common import TrainCalibNode
from .config import MEASUREMENT_TOPIC, REGIME_TOPIC, RESISTANCE_TOPIC, TrainFile
from .convert import regime_input_from_msg, regime_to_cdr, stamp_to_ns
from .runner import run_node

MEASUREMENT_WAIT = 30
"""Estimates held at most waiting for their measurement's power state (none comes: the speeds alone)."""


class RegimeNode(TrainCalibNode):
    NODE_NAME = "regime_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        try:
            self.train = load_train(paths.train_file(self.config(TrainFile).train_file))
        except BaseException:
            self.destroy_node()
            raise
        self._power = PowerEffort(self.train)
        self.stream = RegimeStream(self.config(RegimeConfig))
        self._counts: Counter[int] = Counter()
        self._restarts = 0
        self._held: deque[Any] = deque()  # estimates (RegimeInput) awaiting their measurement's power state
        # (run_id, stamp_ns) -> (power state, TrackMeasurement), ordered by run
        self._powers: dict[tuple[int, int], tuple[int | None, Any]] = {}
        self._newest_measurement: tuple[int, int] = (-1, -1)
        self._with_power = 0
        self.output(DrivingRegime, REGIME_TOPIC)
        self.chain_input(TrackMeasurement, MEASUREMENT_TOPIC, self._on_measurement)  # before: it comes first
        self.chain_input(ResistanceEstimate, RESISTANCE_TOPIC, self._on_estimate)
        cfg = self.classifier.config
        self.get_logger().info(
            f"method {cfg.method}, lag_samples {self.config(RegimeConfig).lag_samples}: {RESISTANCE_TOPIC} -> "
            f"publishing {REGIME_TOPIC}"
        )

    @property
    def classifier(self) -> RegimeClassifier:
        return self.stream.classifier

    @property
    def pending(self) -> int:
        return self.stream.pending + len(self._held)

    def _on_measurement(self, msg: TrackMeasurement) -> None:
        # the message (a read-only view) itself: power_state and the classifier read power_*, s and
        # track_force_integral from it (absent in bags recorded before the field: getattr, NaN)
        key = (int(msg.run_id), stamp_to_ns(msg.header.stamp))
        state = power_state(msg, self._power)
        self._powers[key] = (state, msg)
        self._with_power += state is not None
        if key > self._newest_measurement:
            self._newest_measurement = key
        if self._held:
            self._release()

    def _on_estimate(self, msg: ResistanceEstimate) -> None:
        self._held.append(regime_input_from_msg(msg))
        self._release()

    def _release(self, everything: bool = False) -> None:
        """Classify held estimates, oldest first, once their measurement's power state is known or cannot come."""
        while self._held:
            sample = self._held[0]
            key = (sample.run_id, sample.stamp_ns)
            coming = key not in self._powers and key > self._newest_measurement  # its measurement may still come
            if coming and not everything and len(self._held) <= MEASUREMENT_WAIT:
                return
            self._held.popleft()
            power, m = self._powers.pop(key, (None, None))
            self._publish(self.stream.push(sample, power, m))
            if len(self._powers) > 4 * MEASUREMENT_WAIT:  # measurements without an estimate (rejected) go
                self._powers = {k: p for k, p in self._powers.items() if k > key}

    def _publish(self, triples: list) -> None:
        for sample, regime, phase in triples:
            self._counts[regime] += 1
            self.publish(REGIME_TOPIC, regime_to_cdr(sample, regime, sample.frame_id, phase))

    def end_of_input(self) -> None:
        self._release(everything=True)
        self._publish(self.stream.flush())

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if RegimeConfig in changed:  # a new classifier: the HMM's belief restarts
            self._release(everything=True)
            self._publish(self.stream.flush())
            self.stream = RegimeStream(self.config(RegimeConfig))
            self._restarts += 1

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        out: list[tuple[str, Any]] = [("method", self.classifier.config.method)]
        noise = self.classifier.imm_speed_noise
        if noise is not None:  # imm: the speed noise learned from the second differences
            out.append(("speed noise (imm), m/s", f"{noise:.3f}"))
        out += [(f"samples {name}", self._counts[i]) for i, name in enumerate(REGIME_NAMES)]
        out.append(("measurements with traction power (imm)", self._with_power))
        out.append(("classifier restarts (parameter changes)", self._restarts))
        return out


def main(args: list[str] | None = None) -> int:
    return run_node(RegimeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
