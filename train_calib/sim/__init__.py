"""Train running-time simulator (ROS-free core).

One physics (:mod:`.model`), one Dormand-Prince RK45 integrator with events (:mod:`.integrate`),
two driver strategies:

- :func:`simulate_run`: a realistic driver over time (gentle start, cruise styles, coasting before
  the final brake, ATB-EG brake steps, wind) with sensor models, giving a :class:`SimulatedRun`
  with the truth; :func:`write_run` / :func:`read_truth` store it as a bag plus truth files.
- :func:`running_time_profile`: Besinovic et al.'s minimum-time driver over distance, fast enough
  for a genetic algorithm (a 32 km trajectory in ~2 ms).

See docs/simulator.md.
"""

from .driver import ATB_EG_STEPS_KMH, DriverParams
from .integrate import Event, IntegrationError, StepRecord, integrate
from .model import MotionModel, TrackTerms, Wind
from .phases import BRAKING, COASTING, CRUISING, TRACTION, UNKNOWN
from .run import TRUTH_COLUMNS, GnssStream, PowerStream, SimulatedRun, SpeedStream, Trajectory
from .running_time import Profile, RunningTimeParams, running_time_profile
from .sensors import SensorParams
from .simulator import DEFAULT_START_NS, resolve_stations, simulate_run
from .truthio import TruthFile, read_truth, truth_paths, write_run

__all__ = [
    "ATB_EG_STEPS_KMH",
    "BRAKING",
    "COASTING",
    "CRUISING",
    "DEFAULT_START_NS",
    "TRACTION",
    "TRUTH_COLUMNS",
    "UNKNOWN",
    "DriverParams",
    "Event",
    "GnssStream",
    "IntegrationError",
    "MotionModel",
    "PowerStream",
    "Profile",
    "RunningTimeParams",
    "SensorParams",
    "SimulatedRun",
    "SpeedStream",
    "StepRecord",
    "TrackTerms",
    "Trajectory",
    "TruthFile",
    "Wind",
    "integrate",
    "read_truth",
    "resolve_stations",
    "running_time_profile",
    "simulate_run",
    "truth_paths",
    "write_run",
]
