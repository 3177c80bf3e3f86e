"""Predictions from the calibrated model beside the train file's (issue 24; docs/prediction.md). ROS-free.

- :mod:`.coast`: coasting from (s, v) over distance with the track's g(s), sigma points over (v, r0, r1, r2);
- :mod:`.nominal`: time to the next station under a nominal strategy (traction, cruise, coast, brake);
- :mod:`.predictor`: what /train_calib/prediction holds, per estimate (:class:`Predictor`);
- :mod:`.offline`: ``train-calib predict``: every coast of a recorded run predicted per model, against the bag.
"""

from .coast import CoastResult, GradientIntegral, coast, coast_with_sigma, sigma_points
from .nominal import NominalLeg, nominal_time
from .predictor import ModelPrediction, Prediction, PredictionConfig, Predictor

__all__ = [
    "CoastResult",
    "GradientIntegral",
    "ModelPrediction",
    "NominalLeg",
    "Prediction",
    "PredictionConfig",
    "Predictor",
    "coast",
    "coast_with_sigma",
    "nominal_time",
    "sigma_points",
]
