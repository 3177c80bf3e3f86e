"""Driving features of a run (Cunillera et al. 2022, Sections 3.3, 4.3-4.4), incremental and whole-run.

Every sample after the first closes a *step* (the interval from the previous sample): its duration
dt, its distance, its mean speed v_mid = (v_prev + v) / 2 and the sample's regime, effort (the mean
effort over the step) and acceleration. Steps with v_mid below ``standstill_speed`` are standing time
(regime UNKNOWN). Definitions (docs/estimator.md, "Features"):

* max tractive effort: least-squares line effort = a + b v_mid over TRACTION steps with acceleration > 0
  and v_mid in the effort window; reported at the mean v_mid of those steps (= their mean effort).
* max tractive power: mean and sample std of effort * v_mid over the same kind of steps in the power window.
* brake rate per speed step: mean and sample std of -acceleration over BRAKING samples, binned by speed; a
  sample counts only after ``brake_window`` s of braking and when its speed over that window stayed in one
  step (the acceleration is a window average: transitions and step changes would mix rates).
* cruise speeds: median filtered speed of each CRUISING phase lasting at least ``cruise_min_duration``;
  cruise_speed: the duration-weighted median over the samples of those phases.
* regime time shares: step durations per regime over the run time.
* final brake / final coast (Cunillera 3.3: "the length of the final brake and of the previous coasting
  phase"): duration and distance of the last BRAKING phase (the braking that ends at the stop) and of the
  last COASTING phase (the coasting before it) seen so far. A phase is a maximal run of steps of one regime;
  an interruption up to ``phase_merge_gap`` is merged into it (label noise), except that a coast is never
  continued across braking; it counts when at least ``final_*_min_duration`` of it is labelled with its
  regime. Its start and end are located between samples (``boundary_refinement``): at the break of a
  continuous two-segment line fitted to the speed around the labelled change, searched up to
  ``boundary_search`` before it (the recogniser's latency); the final brake ends where its last speeds
  extrapolate to zero. The simulator's truth uses the same definitions on its exact phases.

Modules: ``rules`` (each rule once, for both paths), ``online`` (``FeatureAccumulator``), ``offline``
(``extract_features``), ``final_phases`` / ``phases`` / ``boundaries`` (final coast and brake, change location),
``brake_rates`` (the online brake-rate bins), ``record`` (``Features`` and how both paths fill it).
"""

from .boundaries import fit_speed, fit_speeds
from .offline import extract_features, features_per_run
from .online import FeatureAccumulator
from .record import Features

__all__ = ["FeatureAccumulator", "Features", "extract_features", "features_per_run", "fit_speed", "fit_speeds"]
