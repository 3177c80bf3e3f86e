"""prediction_node: /train_calib/resistance -> /train_calib/prediction (Prediction), one per estimate.

A thin adapter of :class:`train_calib.prediction.Predictor` (ROS-free): from each estimate's filtered s, v and
r0, r1, r2 with its covariance, coasting to the next station and to the next lower limit (speed, time, sigma) and
the time to the next station under the nominal strategy, with the calibrated r(v) and the train file's side by
side (docs/prediction.md). Parameters: the track and train files and :class:`PredictionConfig`; a change of the
latter applies from the next estimate. Diagnostics: the cost per prediction (mean and max over the period).
"""

from __future__ import annotations

import math
import time
from typing import Any

from train_calib_msgs.msg import Prediction, ResistanceEstimate

from .. import paths
from ..params import ParamSet
from ..prediction import PredictionConfig, Predictor
from ..prediction.predictor import Prediction as PredictionRecord
from ..track import load_track
from ..train import load_train
from .common import TrainCalibNode
from .config import PREDICTION_TOPIC, RESISTANCE_TOPIC, TrackTrainFiles
from .convert import header_msg, stamp_to_ns
from .diagnostics import WARN
from .runner import run_node

COST_WARN_S = 0.05
"""A prediction slower than this (s) is reported as WARN in /diagnostics."""


def prediction_to_msg(p: PredictionRecord, frame_id: str = "") -> Prediction:
    """The Prediction message of a core Prediction record (SI units; NaN where undefined)."""
    m = Prediction()
    m.header = header_msg(p.stamp_ns, frame_id)
    m.run_id = int(p.run_id) & 0xFFFFFFFF
    m.s, m.v = p.s_m, p.v_ms
    m.next_station, m.station_s = p.station_name, p.station_s_m
    m.limit_s, m.limit_v = p.limit_s_m, p.limit_v_ms
    for prefix, model in (("", p.calibrated), ("file_", p.train_file)):
        setattr(m, f"{prefix}r0", model.r[0])
        setattr(m, f"{prefix}r1", model.r[1])
        setattr(m, f"{prefix}r2", model.r[2])
        setattr(m, f"{prefix}coast_station_v", model.station_v_ms)
        setattr(m, f"{prefix}coast_station_v_sigma", model.station_v_sigma_ms)
        setattr(m, f"{prefix}coast_station_time", model.station_t_s)
        setattr(m, f"{prefix}coast_station_time_sigma", model.station_t_sigma_s)
        setattr(m, f"{prefix}coast_limit_v", model.limit_v_ms)
        setattr(m, f"{prefix}coast_limit_v_sigma", model.limit_v_sigma_ms)
        setattr(m, f"{prefix}coast_limit_time", model.limit_t_s)
        setattr(m, f"{prefix}coast_limit_time_sigma", model.limit_t_sigma_s)
        setattr(m, f"{prefix}nominal_station_time", model.nominal_station_t_s)
    return m


class PredictionNode(TrainCalibNode):
    NODE_NAME = "prediction_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        try:
            files = self.config(TrackTrainFiles)
            self.track = load_track(paths.track_file(files.track_file))
            self.train = load_train(paths.train_file(files.train_file))
            self.predictor = Predictor(self.track, self.train, self.config(PredictionConfig))
        except BaseException:
            self.destroy_node()
            raise
        self._cost_sum, self._cost_n, self._cost_max = 0.0, 0, 0.0
        self._last: PredictionRecord | None = None
        self.output(Prediction, PREDICTION_TOPIC)
        self.chain_input(ResistanceEstimate, RESISTANCE_TOPIC, self._on_estimate)
        self.get_logger().info(
            f"track {self.track.name}, train {self.train.name}: {RESISTANCE_TOPIC} -> {PREDICTION_TOPIC} "
            "(coasting to the next station and lower limit, nominal time; calibrated and train file r(v))"
        )

    def _on_estimate(self, msg: Any) -> None:
        t0 = time.perf_counter()
        cov = list(msg.covariance)
        p = self.predictor.predict(stamp_to_ns(msg.header.stamp), int(msg.run_id), float(msg.s), float(msg.v),
                                   [float(msg.r0), float(msg.r1), float(msg.r2)], cov)  # fmt: skip
        self.publish(PREDICTION_TOPIC, prediction_to_msg(p, str(msg.header.frame_id)))
        cost = time.perf_counter() - t0
        self._cost_sum += cost
        self._cost_n += 1
        self._cost_max = max(self._cost_max, cost)
        self._last = p

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if PredictionConfig in changed:
            self.predictor.set_config(self.config(PredictionConfig))

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        out: list[tuple[str, Any]] = []
        if self._cost_n:
            out += [("cost per prediction, mean (ms)", f"{self._cost_sum / self._cost_n * 1e3:.2f}"),
                    ("cost per prediction, max (ms)", f"{self._cost_max * 1e3:.2f}")]  # fmt: skip
        p = self._last
        if p is not None:
            out.append(("next station", p.station_name))
            t = p.calibrated.nominal_station_t_s
            out.append(("nominal time to it (s)", "" if not math.isfinite(t) else f"{t:.0f}"))
        return out

    def diagnostic_problems(self) -> list[tuple[int, str]]:
        problems = []
        if self._cost_n and self._cost_max > COST_WARN_S:
            problems.append((WARN, f"a prediction took {self._cost_max * 1e3:.1f} ms"))
        self._cost_sum, self._cost_n, self._cost_max = 0.0, 0, 0.0
        return problems


def main(args: list[str] | None = None) -> int:
    return run_node(PredictionNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
