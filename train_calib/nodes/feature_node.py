"""feature_node: /train_calib/regime -> /train_calib/features (DrivingFeatures).

Running features of the current run (Cunillera et al. 2022, Sections 3.3, 4.3-4.4) from the core's
:class:`~train_calib.estimation.FeatureAccumulator`, published by the rule of
:class:`~train_calib.pipeline.FeatureStream`: on each regime change, and once with ``run_complete`` true
when the run ends — at the first sample of the next run (a new ``run_id``), at the end of input, or at
shutdown. Parameter changes take effect at the next run.
"""

from __future__ import annotations

from typing import Any

from train_calib_msgs.msg import DrivingFeatures, DrivingRegime

from ..estimation import FeatureConfig, Features
from ..params import ParamSet
from ..pipeline import FeatureStream
from .common import TrainCalibNode
from .config import FEATURES_TOPIC, REGIME_TOPIC
from .convert import features_to_msg, phase_from_msg, regime_input_from_msg
from .runner import run_node


class FeatureNode(TrainCalibNode):
    NODE_NAME = "feature_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.stream = FeatureStream(self.config(FeatureConfig))
        self._frame_id = ""
        self.output(DrivingFeatures, FEATURES_TOPIC)
        self.chain_input(DrivingRegime, REGIME_TOPIC, self._on_regime)
        cfg = self.config(FeatureConfig)
        self.get_logger().info(
            f"brake steps {', '.join(f'{e * 3.6:g}' for e in cfg.brake_step_edges)} km/h: {REGIME_TOPIC} -> publishing "
            f"{FEATURES_TOPIC} on each regime change and once per run"
        )

    def _on_regime(self, msg: DrivingRegime) -> None:
        self._frame_id = msg.header.frame_id
        self._publish(self.stream.update(regime_input_from_msg(msg), phase_from_msg(msg)))  # the paper's phase

    def _publish(self, features: list[Features]) -> None:
        for f in features:
            self.publish(FEATURES_TOPIC, features_to_msg(f, self._frame_id))

    def end_of_input(self) -> None:
        self._publish(self.stream.end_of_input())

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if FeatureConfig in changed:
            self.stream.set_config(self.config(FeatureConfig))

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        run = self.stream.run_id
        return [("run_id", "" if run is None else run), ("runs completed", self.stream.runs_completed)]


def main(args: list[str] | None = None) -> int:
    return run_node(FeatureNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
