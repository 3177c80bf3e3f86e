"""The estimator core (ROS-free): resistance UKF, applied effort, regime recognition, features.

Cunillera et al. (2022) as a library: ``ResistanceEstimator`` per measurement (the ukf node),
``estimate_run`` / ``smooth_run`` on a recorded run, ``RegimeClassifier`` / ``classify_regimes``,
``FeatureAccumulator`` / ``extract_features`` and ``fleet_statistics``. See docs/estimator.md.
"""

from .config import FeatureConfig, RegimeConfig, UKFConfig
from .features import FeatureAccumulator, Features, extract_features, features_per_run
from .fleet import FeatureStatistics, FleetStatistics, fleet_statistics
from .records import (
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    EFFORT_SOURCES,
    HEALTH_DEGRADED,
    HEALTH_OK,
    HEALTH_REPAIRED,
    HEALTH_RESET,
    EstimateSample,
    EstimateSeries,
)
from .regimes import BRAKING, COASTING, CRUISING, REGIME_NAMES, TRACTION, UNKNOWN, RegimeClassifier, classify_regimes
from .run import estimate_run, smooth_run
from .ukf import ResistanceEstimator

__all__ = [
    "BRAKING",
    "COASTING",
    "CRUISING",
    "EFFORT_COASTING",
    "EFFORT_COMPUTED",
    "EFFORT_POWER",
    "EFFORT_POWER_COASTING",
    "EFFORT_SOURCES",
    "HEALTH_DEGRADED",
    "HEALTH_OK",
    "HEALTH_REPAIRED",
    "HEALTH_RESET",
    "REGIME_NAMES",
    "TRACTION",
    "UNKNOWN",
    "EstimateSample",
    "EstimateSeries",
    "FeatureAccumulator",
    "FeatureConfig",
    "FeatureStatistics",
    "Features",
    "FleetStatistics",
    "RegimeClassifier",
    "RegimeConfig",
    "ResistanceEstimator",
    "UKFConfig",
    "classify_regimes",
    "estimate_run",
    "extract_features",
    "features_per_run",
    "fleet_statistics",
    "smooth_run",
]
