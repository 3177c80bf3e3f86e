"""ukf_node: /train_calib/measurement -> /train_calib/resistance (ResistanceEstimate), one per measurement.

The UKF over (s, v, r0, r1, r2) with the applied effort, safeguards and filter health is the core's
(:class:`train_calib.estimation.ResistanceEstimator`). A new ``run_id`` (the ingest's departure after a
standstill) starts a new run; parameter ``carry_over`` decides whether the resistance carries over
(``keep``: r and its covariance, inflated by ``carry_over_inflation``) or restarts from the
manufacturer values of the train file (``reset``, the paper). The covariance is published row-major
over (s, v, r0, r1, r2). UKF parameters changed at run time take effect at the next run.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

from train_calib_msgs.msg import ResistanceEstimate, TrackMeasurement

from .. import paths
from ..estimation import HEALTH_DEGRADED, HEALTH_OK, HEALTH_REPAIRED, HEALTH_RESET, ResistanceEstimator, UKFConfig
from ..estimation.safeguards import SafeguardConfig
from ..params import ParamSet
from ..train import load_train
from .common import TrainCalibNode
from .config import MEASUREMENT_TOPIC, RESISTANCE_TOPIC, TrainFile
from .convert import estimate_to_cdr, measurement_from_msg
from .diagnostics import ERROR, WARN
from .runner import run_node

HEALTH_NAMES = {HEALTH_OK: "ok", HEALTH_REPAIRED: "repaired", HEALTH_DEGRADED: "degraded", HEALTH_RESET: "reset"}


class UkfNode(TrainCalibNode):
    NODE_NAME = "ukf_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        try:
            self.train = load_train(paths.train_file(self.config(TrainFile).train_file))
            self.estimator = ResistanceEstimator(
                self.train, self.config(UKFConfig), safeguards=self._safeguard_config()
            )
        except BaseException:
            self.destroy_node()
            raise
        self._next_config: UKFConfig | None = None
        self._run_id: int | None = None
        self._health = Counter()
        self._health_reported = Counter()
        self._last = None
        self.output(ResistanceEstimate, RESISTANCE_TOPIC)
        self.chain_input(TrackMeasurement, MEASUREMENT_TOPIC, self._on_measurement)
        d = self.train.davis
        self.get_logger().info(
            f"train {self.train.name}: manufacturer r0 {d.r0:g} N/kg, r1 {d.r1:g}, r2 {d.r2:g}; "
            f"carry_over {self.config(UKFConfig).carry_over}"
        )

    def _on_measurement(self, msg: TrackMeasurement) -> None:
        m = measurement_from_msg(msg)
        if m.run_id != self._run_id:
            if self._next_config is not None:  # parameters changed: a new filter for the new run
                cfg, self._next_config = self._next_config, None
                keep = cfg.carry_over == "keep" and self._run_id is not None
                self.estimator.flush()  # the old run's samples still waiting for the look-ahead inform r first
                self.estimator = ResistanceEstimator(
                    self.train, cfg, self.estimator.davis if keep else None, safeguards=self._safeguard_config()
                )
            self._run_id = m.run_id
        estimate = self.estimator.update(m)
        if self.estimator.rejected is not None:  # not a usable measurement: counted, nothing published
            self.drop(MEASUREMENT_TOPIC, self.estimator.rejected)
            return
        self._health[estimate.health] += 1
        self._last = estimate
        self.publish(RESISTANCE_TOPIC, estimate_to_cdr(estimate, msg.header.frame_id))

    def _safeguard_config(self) -> SafeguardConfig:
        return self.config(SafeguardConfig)

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if UKFConfig in changed or SafeguardConfig in changed:
            self._next_config = self.config(UKFConfig)

    def refresh_counters(self) -> None:
        repaired = self.estimator.counters["input_repaired"]
        if repaired:
            self.set_repairs(MEASUREMENT_TOPIC, {"invalid_value": repaired})

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        out: list[tuple[str, Any]] = []
        e = self._last
        if e is not None:
            std = [math.sqrt(max(float(e.covariance[i, i]), 0.0)) for i in range(5)]
            out += [
                ("filter health", HEALTH_NAMES.get(e.health, str(e.health))),
                ("run_id", e.run_id),
                ("r0 (N/kg)", f"{e.r0:.6g} +- {std[2]:.2g}"),
                ("r1 (N/(kg m/s))", f"{e.r1:.6g} +- {std[3]:.2g}"),
                ("r2 (N/(kg (m/s)^2))", f"{e.r2:.6g} +- {std[4]:.2g}"),
                ("nis", f"{e.nis:.3f}"),
            ]
        out += [(f"health {HEALTH_NAMES[h]}", self._health[h]) for h in HEALTH_NAMES]
        out += [(f"filter {k}", v) for k, v in self.estimator.counters.items()]
        return out

    def diagnostic_problems(self) -> list[tuple[int, str]]:
        new = self._health - self._health_reported
        self._health_reported = Counter(self._health)
        problems = []
        if new[HEALTH_RESET]:
            problems.append((ERROR if new[HEALTH_RESET] > 1 else WARN, f"filter reset {new[HEALTH_RESET]} times"))
        if new[HEALTH_DEGRADED]:
            problems.append((WARN, f"innovations inconsistent (NIS) on {new[HEALTH_DEGRADED]} updates"))
        if new[HEALTH_REPAIRED]:
            problems.append((WARN, f"covariance repaired {new[HEALTH_REPAIRED]} times"))
        unseen = self.estimator.power_braking_unseen()
        if unseen:
            problems.append(
                (WARN, f"braking without regenerated power on {unseen} steps: no electric brake or no regeneration "
                       "metered? set power_coasting false")
            )  # fmt: skip
        return problems


def main(args: list[str] | None = None) -> int:
    return run_node(UkfNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
