"""gnss_speed_node: GNSS fixes + speed (+ traction power) -> /train_calib/measurement (TrackMeasurement).

Map matching with continuity, pairing by stamp, validation with counted drop reasons, g(s) over the
train length and run segmentation are the core's (:class:`train_calib.ingest.Ingest`); this node
converts messages, publishes one TrackMeasurement per accepted speed sample (``header.frame_id`` = the
track name) and reports the drops on /diagnostics.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import NavSatFix
from train_calib_msgs.msg import TrackMeasurement, TractionPower

from .. import paths
from ..bagio import GNSS_TOPIC, POWER_TOPIC, SPEED_TOPIC
from ..errors import ConfigError
from ..ingest import (
    GNSS,
    POWER,
    SPEED,
    Ingest,
    IngestConfig,
    fix_from_msg,
    power_from_msg,
    speed_from_msg,
)
from ..measurement import Measurement
from ..params import ParamSet
from ..track import load_track
from ..train import load_train
from .common import TrainCalibNode
from .config import MEASUREMENT_TOPIC, TrackTrainFiles
from .convert import measurement_to_cdr
from .diagnostics import WARN
from .runner import run_node

STREAM_TOPICS = {GNSS: GNSS_TOPIC, SPEED: SPEED_TOPIC, POWER: POWER_TOPIC}


class GnssSpeedNode(TrainCalibNode):
    NODE_NAME = "gnss_speed_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        files = self.config(TrackTrainFiles)
        try:
            self.track = load_track(paths.track_file(files.track_file))
            self.train = load_train(paths.train_file(files.train_file))
            self.ingest = Ingest(self.track, self.train, self.config(IngestConfig))
        except BaseException:
            self.destroy_node()
            raise
        self._frame_id = self.track.name
        self._clock_resets_reported = 0
        self.output(TrackMeasurement, MEASUREMENT_TOPIC)
        self.sensor_input(NavSatFix, GNSS_TOPIC, self._on_fix)
        self.sensor_input(TwistStamped, SPEED_TOPIC, self._on_speed)
        self.sensor_input(TractionPower, POWER_TOPIC, self._on_power)
        self.get_logger().info(
            f"track {self.track.name} ({self.track.length_m:.0f} m), train {self.train.name} "
            f"({self.train.length_m:.0f} m): publishing {MEASUREMENT_TOPIC}"
        )

    # -- callbacks --------------------------------------------------------------------------------
    def _on_fix(self, msg: NavSatFix) -> None:
        self._emit(self.ingest.add_fix(fix_from_msg(msg)))

    def _on_speed(self, msg: TwistStamped) -> None:
        self._emit(self.ingest.add_speed(speed_from_msg(msg)))

    def _on_power(self, msg: TractionPower) -> None:
        self._emit(self.ingest.add_power(power_from_msg(msg)))

    def _emit(self, measurements: list[Measurement]) -> None:
        for m in measurements:
            self.publish(MEASUREMENT_TOPIC, measurement_to_cdr(m, self._frame_id))

    def end_of_input(self) -> None:
        self._emit(self.ingest.flush())

    @property
    def pending(self) -> int:
        return self.ingest.pending

    # -- parameters -------------------------------------------------------------------------------
    def check_config(self, cfg: ParamSet) -> str | None:
        if isinstance(cfg, IngestConfig):
            try:
                self.ingest.start_position(cfg)
            except ConfigError as exc:
                return exc.problem
        return None

    def on_parameters_changed(self, changed: set[type[ParamSet]]) -> None:
        if IngestConfig in changed:
            self.ingest.set_config(self.config(IngestConfig))

    # -- diagnostics ------------------------------------------------------------------------------
    def refresh_counters(self) -> None:
        for stream, topic in STREAM_TOPICS.items():
            self.set_drops(topic, self.ingest.stats.dropped[stream])
            self.set_repairs(topic, self.ingest.stats.repaired[stream])

    def diagnostic_values(self) -> list[tuple[str, Any]]:
        st = self.ingest.stats
        delay = self.ingest.gnss_delay_estimate
        return [
            ("position acquired", self.ingest.acquired),
            ("run_id", self.ingest.run_id),
            ("re-acquisitions", st.reacquisitions),
            ("dead-reckoned measurements", st.dead_reckoned),
            ("held for pairing", self.ingest.pending),
            ("direction", "reversing" if self.ingest.reversing else "forward"),
            ("reversals", st.reversals),
            ("clock resets", st.clock_resets),
            ("gnss delay estimate (s)", "unknown" if delay is None else f"{delay[0]:.2f} +- {delay[1]:.2f}"),
        ]

    def diagnostic_problems(self) -> list[tuple[int, str]]:
        ingest, cfg, st = self.ingest, self.ingest.config, self.ingest.stats
        problems: list[tuple[int, str]] = []
        if self.handled[SPEED_TOPIC] and not ingest.acquired:
            problems.append((WARN, "no position: no fix on the track yet"))
        for stream, topic in STREAM_TOPICS.items():
            n = st.consecutive_dropped[stream]
            if n >= cfg.drop_warn_count:
                problems.append((WARN, f"{topic}: the last {n} samples were dropped ({st.last_drop.get(stream)})"))
        if ingest.reversing:
            problems.append((WARN, "moving against the track direction: speed samples dropped (reversing)"))
        delay = ingest.gnss_delay_estimate
        if delay is not None and abs(delay[0]) > cfg.delay_warn and abs(delay[0]) > 3.0 * delay[1]:
            hint = f"set gnss_delay to {cfg.gnss_delay + delay[0]:.2f}"
            problems.append((WARN, f"GNSS stamps {delay[0]:+.2f} s off the speed stamps ({hint})"))
        if st.clock_resets > self._clock_resets_reported:
            problems.append((WARN, f"clock reset: stamps jumped back ({st.clock_resets} in total); a new run"))
            self._clock_resets_reported = st.clock_resets
        return problems


def main(args: list[str] | None = None) -> int:
    return run_node(GnssSpeedNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
