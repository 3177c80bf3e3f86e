"""What the prediction node publishes after each estimate, ROS-free: :class:`Predictor`.

From the estimate's filtered (s, v), with the calibrated r(v) (the estimate's r0, r1, r2 and the 4x4 covariance over
v, r0, r1, r2 from its 5x5) and with the train file's r(v) (its covariance the estimator's prior,
:func:`train_calib.estimation.coast_posterior.prior_covariance`):

- coasting from here to the next station and to the start of the next lower speed limit: speed (m/s) and time (s)
  there, each with its sigma (:func:`.coast.coast_with_sigma`; speed 0 and time NaN where the coast stops first);
- the time to the next station under the nominal strategy (:func:`.nominal.nominal_time`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..estimation.coast_posterior import prior_covariance
from ..params import ParamSet, param
from ..sim.limits import SpeedCeiling
from ..sim.model import TrackTerms
from ..track import Track
from ..train import TrainSpec
from .coast import GradientIntegral, coast_with_sigma
from .nominal import NominalLeg, nominal_time


@dataclass(frozen=True)
class PredictionConfig(ParamSet):
    """Coasting and nominal-strategy predictions from the current estimate (docs/prediction.md)."""

    coast_step: float = param(800.0, "largest step of the coasting integration (RK4 over distance)", unit="m",
                                low=1.0, high=5000.0)  # fmt: skip
    coast_max_steps: int = param(40, "most steps of one coasting integration (longer ones take longer steps)",
                                 low=4, high=100000)  # fmt: skip
    nominal_coast_distance: float = param(2000.0, "nominal strategy: coasting starts this far before the station",
                                          unit="m", low=0.0)  # fmt: skip
    nominal_resume_fraction: float = param(0.5, "nominal strategy: a coast below this fraction of the limit "
                                           "resumes traction", low=0.0, high=1.0)  # fmt: skip
    nominal_step: float = param(100.0, "nominal strategy: integration step", unit="m", low=1.0, high=1000.0)
    station_margin: float = param(20.0, "a station less than this ahead is the one the train is at, not the next",
                                  unit="m", low=0.0)  # fmt: skip
    train_file_scale_std: float = param(0.18, "sigma of the train file's r(v): common relative std (the "
                                        "estimator's prior_scale_std)", low=0.0)  # fmt: skip
    train_file_coefficient_std: float = param(0.10, "sigma of the train file's r(v): per-coefficient relative std "
                                              "(the estimator's prior_coefficient_std)", low=0.0)  # fmt: skip


@dataclass
class ModelPrediction:
    """One model's predictions (SI units; NaN where undefined)."""

    r: tuple[float, float, float]  # r0 N/kg, r1 N/(kg m/s), r2 N/(kg (m/s)^2)
    station_v_ms: float = math.nan  # coasting: speed at the next station (0: stops before)
    station_v_sigma_ms: float = math.nan
    station_t_s: float = math.nan  # coasting: time to the next station (NaN: stops before)
    station_t_sigma_s: float = math.nan
    limit_v_ms: float = math.nan  # coasting: speed at the start of the next lower limit
    limit_v_sigma_ms: float = math.nan
    limit_t_s: float = math.nan
    limit_t_sigma_s: float = math.nan
    nominal_station_t_s: float = math.nan  # nominal strategy: time to the stop at the next station


@dataclass
class Prediction:
    """The contents of one /train_calib/prediction message."""

    stamp_ns: int
    run_id: int
    s_m: float
    v_ms: float
    station_name: str
    station_s_m: float  # NaN: no station ahead
    limit_s_m: float  # start of the next lower limit (head), NaN: none ahead
    limit_v_ms: float  # that limit, m/s
    calibrated: ModelPrediction
    train_file: ModelPrediction


class Predictor:
    """Predictions on one track for one train; ``predict`` per estimate."""

    def __init__(self, track: Track, train: TrainSpec, config: PredictionConfig | None = None) -> None:
        self.track, self.train = track, train
        self.config = config if config is not None else PredictionConfig()
        self.terms = TrackTerms(track, train.length_m)
        self.G = GradientIntegral(self.terms)
        v_max = train.max_speed_kmh / 3.6 if train.max_speed_kmh > 0 else math.inf
        drops = SpeedCeiling(track, train.length_m, 0.0, track.length_m, v_max).drops()
        self._drop_s = np.array([d.s_m for d in drops])
        self._drop_v = np.array([d.v_low for d in drops])
        self._station_s = np.array([st.s_m for st in track.stations])
        self._legs: dict[int, NominalLeg] = {}
        self.file_r = np.array(train.davis.as_tuple())
        c = self.config
        self.file_cov = prior_covariance(train.davis, c.train_file_scale_std, c.train_file_coefficient_std)

    def set_config(self, config: PredictionConfig) -> None:
        self.__init__(self.track, self.train, config)  # type: ignore[misc]

    def next_station(self, s_m: float) -> int | None:
        i = int(np.searchsorted(self._station_s, s_m + self.config.station_margin, side="right"))
        return i if i < self._station_s.size else None

    def next_drop(self, s_m: float) -> int | None:
        i = int(np.searchsorted(self._drop_s, s_m, side="right"))
        return i if i < self._drop_s.size else None

    def leg(self, station: int) -> NominalLeg:
        leg = self._legs.get(station)
        if leg is None:
            leg = self._legs[station] = NominalLeg(
                self.track, self.train, self.terms, float(self._station_s[station]), self.config.nominal_step
            )
        return leg

    def predict(self, stamp_ns: int, run_id: int, s_m: float, v_ms: float, r: np.ndarray, covariance: np.ndarray
                ) -> Prediction:  # fmt: skip
        """From the filtered s (m), v (m/s), r = (r0, r1, r2) and the 5x5 covariance over (s, v, r0, r1, r2)."""
        c = self.config
        r = np.asarray(r, dtype=float)
        cov = np.asarray(covariance, dtype=float).reshape(5, 5)
        st, dr = self.next_station(s_m), self.next_drop(s_m)
        station_s = float(self._station_s[st]) if st is not None else math.nan
        limit_s = float(self._drop_s[dr]) if dr is not None else math.nan
        out = Prediction(stamp_ns, run_id, float(s_m), float(v_ms),
                         self.track.stations[st].name if st is not None else "", station_s, limit_s,
                         float(self._drop_v[dr]) if dr is not None else math.nan,
                         ModelPrediction(tuple(r.tolist())), ModelPrediction(tuple(self.file_r.tolist())))  # fmt: skip
        targets = [x for x in (station_s, limit_s) if math.isfinite(x)]
        if not targets or not math.isfinite(v_ms):
            return out
        order = np.argsort(targets)
        tgt = np.asarray(targets)[order]
        var_v = max(float(cov[1, 1]), 0.0)
        cal_cov = cov[1:, 1:]
        file_cov = np.zeros((4, 4))
        file_cov[0, 0] = var_v
        file_cov[1:, 1:] = self.file_cov
        models = [(np.concatenate(([v_ms], r)), cal_cov), (np.concatenate(([v_ms], self.file_r)), file_cov)]
        results = coast_with_sigma(self.terms, self.G, float(s_m), models, tgt, tunnel_factor=self.train.tunnel_factor,
                                   ds_max_m=c.coast_step, max_steps=c.coast_max_steps)  # fmt: skip
        for model, (v, vs, t, ts) in zip((out.calibrated, out.train_file), results):
            for j, k in enumerate(order):
                values = (float(v[j]), float(vs[j]), float(t[j]), float(ts[j]))
                if targets[k] == station_s and k == 0 and math.isfinite(station_s):
                    model.station_v_ms, model.station_v_sigma_ms, model.station_t_s, model.station_t_sigma_s = values
                else:
                    model.limit_v_ms, model.limit_v_sigma_ms, model.limit_t_s, model.limit_t_sigma_s = values
            if st is not None:
                model.nominal_station_t_s = nominal_time(
                    self.leg(st), self.train, model.r, float(s_m), float(v_ms),
                    coast_distance_m=c.nominal_coast_distance, resume_fraction=c.nominal_resume_fraction,
                )  # fmt: skip
        return out
