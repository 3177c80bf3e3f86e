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
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from train_calib_msgs.msg import DrivingRegime, ResistanceEstimate

from ..estimation import REGIME_NAMES, RegimeClassifier, RegimeConfig
from ..params import ParamSet
from ..pipeline import RegimeStream
from .common import TrainCalibNode, run_node
from .config import REGIME_TOPIC, RESISTANCE_TOPIC
from .convert import regime_input_from_msg, regime_to_cdr


class RegimeNode(TrainCalibNode):
    NODE_NAME = "regime_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.stream = RegimeStream(self.config(RegimeConfig))
        self._counts: Counter[int] = Counter()
        self._restarts = 0
        self.output(DrivingRegime, REGIME_TOPIC)
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
        return self.stream.pending

    def _on_estimate(self, msg: ResistanceEstimate) -> None:
        self._publish(self.stream.push(regime_input_from_msg(msg)))

    def _publish(self, triples: list) -> None:
        for sample, regime, phase in triples:
            self._counts[regime] += 1
            self.publish(REGIME_TOPIC, regime_to_cdr(sample, regime, sample.frame_id, phase))

    def end_of_input(self) -> None:
        self._publish(self.stream.flush())

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if RegimeConfig in changed:  # a new classifier: the HMM's belief restarts
            self._publish(self.stream.flush())
            self.stream = RegimeStream(self.config(RegimeConfig))
            self._restarts += 1

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        out: list[tuple[str, Any]] = [("method", self.classifier.config.method)]
        noise = self.classifier.imm_speed_noise
        if noise is not None:  # imm: the speed noise learned from the second differences
            out.append(("speed noise (imm), m/s", f"{noise:.3f}"))
        out += [(f"samples {name}", self._counts[i]) for i, name in enumerate(REGIME_NAMES)]
        out.append(("classifier restarts (parameter changes)", self._restarts))
        return out


def main(args: list[str] | None = None) -> int:
    return run_node(RegimeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
