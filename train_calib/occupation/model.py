"""The running-time model the calibration calls: a thin wrapper of ``train_calib.sim``'s fast model.

:func:`train_calib.sim.running_time.running_time_profile` is Besinovic's accelerate / cruise / brake
model integrated over distance with RK45; :func:`train_calib.sim.running_time_batch.running_time_batch`
is the same model for a whole population of parameter vectors in one call (what differential
evolution uses, one call per generation). :class:`SimulatorModel` binds them to a track and to the
composition's fixed parameters and maps a parameter mapping (:data:`~.compositions.MODEL_NAMES`
plus ``length_m``) onto :class:`~train_calib.sim.running_time.RunningTimeParams`. A parameter vector
with which the train cannot start or stalls on a gradient gives a profile of NaN times, which the
objective turns into a penalty (the optimiser then avoids that corner of the box).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from ..errors import TrainCalibError
from ..sim.integrate import IntegrationError
from ..sim.running_time import Profile, RunningTimeParams, running_time_profile
from ..sim.running_time_batch import BATCH_FIELDS, ProfileBatch, running_time_batch
from ..track import Track
from ..train import load_train
from .compositions import MODEL_NAMES, Composition


class FailedProfile:
    """Stands in for a profile the model could not compute (the train cannot start or stalls)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason

    def time_at(self, s_m) -> np.ndarray:
        return np.full(np.shape(s_m), np.nan)

    def speed_at(self, s_m) -> np.ndarray:
        return np.full(np.shape(s_m), np.nan)


class SimulatorModel:
    """model(params, start_m, stop_m) -> Profile, for one track and one composition.

    The composition's train file supplies what is not calibrated and not in the paper's model
    (maximum speed, tunnel factor); the adhesion cap is off, as in the paper's eq. 4 (c0 is the
    effort limit at standstill). Picklable, so differential evolution can ship it to workers.
    """

    def __init__(self, track: Track, composition: Composition | None = None, *, rtol: float = 1e-7) -> None:
        self.track = track
        self.rtol = rtol
        self.failures = 0
        self.last_failure = ""
        base = RunningTimeParams()
        if composition is not None and composition.train_file:
            base = RunningTimeParams.from_train(load_train(composition.train_file))
        self.base = dataclasses.replace(base, adhesive_mass_fraction=0.0)
        if composition is not None:
            self.base = dataclasses.replace(self.base, **composition.model_params())

    def params(self, values: Mapping[str, float]) -> RunningTimeParams:
        """RunningTimeParams with ``values`` (model names and length_m) over the base."""
        changes = {k: float(values[k]) for k in (*MODEL_NAMES, "length_m") if k in values}
        return dataclasses.replace(self.base, **changes)

    def batch(self, values: Mapping[str, float | np.ndarray], start_m: float, stop_m: float) -> ProfileBatch:
        """Profiles of n parameter vectors at once: ``values`` maps names to arrays of length n or numbers.

        The train length must be one number for the whole batch. Members the model cannot run (the
        train cannot start or stalls) have ``ok`` False and NaN times; they are counted in ``failures``.
        """
        base = self.base
        if "length_m" in values:
            lengths = np.unique(np.asarray(values["length_m"], dtype=float))
            if lengths.size != 1:
                raise ValueError("a batch has one train length")
            base = dataclasses.replace(base, length_m=float(lengths[0]))
        per = {k: values[k] for k in BATCH_FIELDS if k in values}
        out = running_time_batch(self.track, base, start_m, stop_m, rtol=self.rtol, **per)
        bad = ~out.ok
        if bad.any():
            self.failures += int(np.count_nonzero(bad))
            self.last_failure = out.error[int(np.argmax(bad))]
        return out

    def __call__(self, values: Mapping[str, float], start_m: float, stop_m: float) -> Profile | FailedProfile:
        try:
            return running_time_profile(self.track, self.params(values), start_m, stop_m, rtol=self.rtol)
        except (TrainCalibError, IntegrationError, RuntimeError, ArithmeticError, ValueError) as exc:
            # TrainCalibError: cannot start / stalls (expected in a corner of the box); the others are
            # numerical failures of the integrator, counted so that a calibration can report them
            self.failures += 1
            self.last_failure = f"{type(exc).__name__}: {exc}"
            return FailedProfile(self.last_failure)
