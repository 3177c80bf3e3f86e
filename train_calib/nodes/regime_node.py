"""regime_node: /train_calib/resistance -> /train_calib/regime (DrivingRegime), one per estimate.

The rule (Cunillera et al. 2022, Section 3.2) is the core's :class:`~train_calib.estimation.RegimeClassifier`
on the estimate's effort, acceleration and filtered speed (standing is UNKNOWN). Threshold changes take
effect at once (the rule has no state).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from train_calib_msgs.msg import DrivingRegime, ResistanceEstimate

from ..estimation import REGIME_NAMES, RegimeClassifier, RegimeConfig
from ..params import ParamSet
from .common import TrainCalibNode, run_node
from .config import REGIME_TOPIC, RESISTANCE_TOPIC
from .convert import regime_input_from_msg, regime_to_msg


class RegimeNode(TrainCalibNode):
    NODE_NAME = "regime_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.classifier = RegimeClassifier(self.config(RegimeConfig))
        self._counts: Counter[int] = Counter()
        self.output(DrivingRegime, REGIME_TOPIC)
        self.chain_input(ResistanceEstimate, RESISTANCE_TOPIC, self._on_estimate)

    def _on_estimate(self, msg: ResistanceEstimate) -> None:
        sample = regime_input_from_msg(msg)
        regime = self.classifier.classify(sample.effort, sample.acceleration, sample.v)
        self._counts[regime] += 1
        self.publish(REGIME_TOPIC, regime_to_msg(sample, regime, msg.header.frame_id))

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if RegimeConfig in changed:
            self.classifier = RegimeClassifier(self.config(RegimeConfig))

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        return [(f"samples {name}", self._counts[i]) for i, name in enumerate(REGIME_NAMES)]


def main(args: list[str] | None = None) -> int:
    return run_node(RegimeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
