"""The node graph's chain without ROS: Ingest -> ResistanceEstimator -> RegimeClassifier -> features, and the
sliding-window calibration with traction power (WindowCalibrator) after the regime.

``Pipeline`` does per sample exactly what the nodes do per message (the same core objects, called in
the same order with the same values), so replaying a bag through the graph and running
``run_bag(bag)`` on it give the same numbers, message for message; a test checks this. Use it for
offline work on bags or on a MeasurementSeries, and as the reference of the graph.

:func:`classify_estimate` is regime_node's call of the classifier (shared, so the two cannot drift).

:class:`FeatureStream` is the feature node's publication rule (shared with ``feature_node``): features
on each regime change, and once with ``run_complete`` when the run ends (next run_id, end of input).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .bagio import GNSS_TOPIC, INPUT_TOPICS, POWER_TOPIC, SPEED_TOPIC, iter_bag
from .cdr_inputs import read_input_events
from .estimation import (
    FeatureAccumulator,
    FeatureConfig,
    Features,
    RegimeClassifier,
    RegimeConfig,
    ResistanceEstimator,
    UKFConfig,
)
from .estimation.coast_regression import CoastFit, CoastSettings, RunArrays, fit_coasts
from .estimation.effort import PowerEffort
from .estimation.records import EFFORT_COMPUTED, EstimateSample
from .estimation.regime_model import power_state
from .estimation.regimes_whole_run import ESTIMATE_COLUMNS, classify_whole_run
from .estimation.safeguards import SafeguardConfig
from .ingest import Ingest, IngestConfig, IngestStats, fix_from_msg, power_from_msg, speed_from_msg
from .measurement import Measurement, MeasurementSeries
from .track import Track
from .train import Davis, TrainSpec
from .window import WindowCalibrator, WindowConfig, WindowFit
from .window.pooled import pooled_summary


@dataclass(slots=True)
class RegimeRecord:
    """One /train_calib/regime message (DrivingRegime.msg fields, SI units); slots: one is made per sample."""

    stamp_ns: int
    run_id: int
    regime: int
    s: float
    v: float
    effort: float
    acceleration: float
    v_measured: float = math.nan  # the speed measurement, m/s
    effort_source: int = EFFORT_COMPUTED  # EFFORT_* of the estimate
    phase: int = 0  # the paper's phase (RegimeClassifier.phase; features and window calibration use it)


def classify_estimate(
    classifier: RegimeClassifier, estimate: Any, power: int | None = None, measurement: Any = None
) -> int:
    """The driving regime of one estimate, as regime_node and :class:`Pipeline` classify it; its phase is
    ``classifier.phase`` afterwards.

    `estimate` has ``stamp_ns``, ``effort`` (N/kg), ``acceleration`` (m/s^2), ``v`` (m/s), ``v_measured`` (m/s),
    ``effort_known`` and ``resistance`` + ``track_force`` (N/kg; an EstimateSample or a ResistanceEstimate as a
    ``RegimeInput``). The classifier gets ``effort_known`` and ``opposing_force`` = resistance + track_force, the
    force the effort works against: with them the HMM uses the exact r + g on every sample and, where the effort
    comes from measured traction power, the instantaneous net acceleration effort - (r + g); the IMM (the default)
    the measured speed and the time (docs/estimator.md, Regimes), and ``power``, the state of the measurement's
    traction power (``power_state``; None: not measured), and from the estimate's ``measurement`` (a Measurement,
    optional) its s and ``track_force_integral``, for the mean g over the step. Fields that are None are not passed.
    """
    resistance, track_force = estimate.resistance, estimate.track_force
    w = None if resistance is None or track_force is None else resistance + track_force
    return classifier.classify(
        estimate.effort,
        estimate.acceleration,
        estimate.v,
        effort_known=estimate.effort_known,
        opposing_force=w,
        speed_measured=getattr(estimate, "v_measured", None),
        time=estimate.stamp_ns * 1e-9,
        power=power,
        track_force=track_force,
        position=None if measurement is None else measurement.s,
        track_force_integral=None if measurement is None else getattr(measurement, "track_force_integral", None),
    )


class RegimeStream:
    """regime_node's publication rule (shared with :class:`Pipeline`): ``push(sample)`` classifies an estimate and
    returns the (sample, regime, phase) triples to publish now, in order. With ``lag_samples`` 0 that is the sample
    itself; with 1 (the default) the previous sample, revised with this one: with ``imm`` its regime
    (``RegimeClassifier.revised_previous_regime``: the mode probabilities smoothed over one more step, and the
    regime at its instant where a change fell inside a long step around it), its phase the causal one; with ``hmm``
    its phase, which is the regime (``RegimeClassifier.revised_previous``); its causal labels where this sample does
    not inform it (e.g. a new run). This one is held until the next or ``flush()`` (end of input).
    Samples carry ``run_id``; the held one is released with its causal labels when a sample of another run comes."""

    def __init__(self, config: RegimeConfig | None = None) -> None:
        self.config = config if config is not None else RegimeConfig()
        self.classifier = RegimeClassifier(self.config)
        self._lag = self.config.lag_samples > 0
        self._held: tuple[Any, int, int] | None = None

    @property
    def pending(self) -> int:
        """Samples classified but not yet released."""
        return int(self._held is not None)

    def push(self, sample: Any, power: int | None = None, measurement: Any = None) -> list[tuple[Any, int, int]]:
        regime = classify_estimate(self.classifier, sample, power, measurement)
        phase = self.classifier.phase
        if not self._lag:
            return [(sample, regime, phase)]
        out = []
        if self._held is not None:
            held, held_regime, held_phase = self._held
            if held.run_id == sample.run_id:
                held_regime, held_phase = self.classifier.revised_labels(held_regime, held_phase)
            out.append((held, held_regime, held_phase))
        self._held = (sample, regime, phase)
        return out

    def flush(self) -> list[tuple[Any, int, int]]:
        """Release the held sample with its causal labels (end of input)."""
        held, self._held = self._held, None
        return [held] if held is not None else []


class FeatureStream:
    """Features to publish per regime sample: on a regime change, and ``run_complete`` at the end of a run.

    ``on_change`` False: only the ``run_complete`` ones (a fleet row reads nothing else; a snapshot changes no state
    of the accumulator, so the closing features are the same)."""

    def __init__(self, config: FeatureConfig | None = None, on_change: bool = True) -> None:
        self.on_change = on_change
        self.config = config if config is not None else FeatureConfig()
        self.accumulator = FeatureAccumulator(self.config)
        self.run_id: int | None = None
        self.complete = False
        self.runs_completed = 0
        self._next_config: FeatureConfig | None = None

    def set_config(self, config: FeatureConfig) -> None:
        """Takes effect at the next run."""
        self._next_config = config

    def update(self, sample: Any, regime: int) -> list[Features]:
        """`sample` has stamp_ns, run_id, s, v, effort, acceleration (an estimate or a regime record)."""
        out = []
        if sample.run_id != self.run_id:
            out += self.end_of_input()
            if self._next_config is not None:
                self.config, self._next_config = self._next_config, None
                self.accumulator = FeatureAccumulator(self.config)
            self.run_id, self.complete = int(sample.run_id), False
        if self.accumulator.update(sample, int(regime)) and self.on_change:
            out.append(self.accumulator.snapshot())
        return out

    def end_of_input(self) -> list[Features]:
        """Close the current run (once)."""
        if self.run_id is None or self.complete:
            return []
        self.complete = True
        self.runs_completed += 1
        return [self.accumulator.snapshot(run_complete=True)]


@dataclass
class PipelineOutput:
    """Everything the graph would publish, per output topic, in publication order."""

    measurements: list[Measurement] = field(default_factory=list)
    estimates: list[EstimateSample] = field(default_factory=list)
    regimes: list[RegimeRecord] = field(default_factory=list)
    features: list[Features] = field(default_factory=list)
    windows: list[WindowFit] = field(default_factory=list)  # /train_calib/window_resistance (with traction power)
    best: CoastFit | None = None  # the whole run's best estimate (offline coast regression), after end_of_input
    ingest_stats: IngestStats | None = None

    @property
    def final(self) -> EstimateSample | None:
        return self.estimates[-1] if self.estimates else None

    @property
    def window_pooled(self) -> dict[str, object] | None:
        """The last window's pooled r(v) as summary.json's ``window.pooled`` (None without windows)."""
        return pooled_summary(self.windows[-1].pooled, self.windows[-1].pooled_covariance,
                              self.windows[-1].pooled_windows) if self.windows else None  # fmt: skip


class Pipeline:
    """Online chain of the core boxes; feed ingest events (or measurements), then ``end_of_input()``.

    ``window``: the sliding-window calibration as window_calib_node runs it -- True (the default: WindowConfig()),
    a WindowConfig, or False (the graph without window_calib_node). It yields results only for measurements that
    carry traction power, so with the default the pipeline equals the replay's graph, which starts
    window_calib_node when the bag has /train/traction_power. ``feature_changes`` False: features only at the end
    of each run (``FeatureStream.on_change``), as a fleet row needs them. ``regime_labels`` False: the regime
    records carry the phase as their regime too (with ``imm``, its ``hmm`` runs alone: the same phases, so the same
    features and windows), for a caller that reads no regime (a fleet row).
    """

    def __init__(
        self,
        track: Track | None,
        train: TrainSpec,
        *,
        ingest: IngestConfig | None = None,
        ukf: UKFConfig | None = None,
        regime: RegimeConfig | None = None,
        features: FeatureConfig | None = None,
        initial: Davis | None = None,
        safeguards: SafeguardConfig | None = None,
        window: WindowConfig | bool = True,
        feature_changes: bool = True,
        regime_labels: bool = True,
    ) -> None:
        self.ingest = Ingest(track, train, ingest) if track is not None else None
        self.estimator = ResistanceEstimator(train, ukf, initial, safeguards)
        regime = regime if regime is not None else RegimeConfig()
        if not regime_labels and regime.method == "imm":  # the phase alone: the imm's hmm, without the imm
            regime = replace(regime, method="hmm", lag_samples=0)  # beside the imm the phase is never revised
        self.regimes = RegimeStream(regime)
        self._power = PowerEffort(train)  # the traction power's state for the regimes
        self.features = FeatureStream(features, feature_changes)
        self.window: WindowCalibrator | None = None
        if window is not False:
            self.window = WindowCalibrator(train, WindowConfig() if window is True else window)
        self.out = PipelineOutput(ingest_stats=self.ingest.stats if self.ingest is not None else None)
        self._measurements_held: deque[tuple[Measurement, bool]] = deque()  # (m, has an estimate) awaiting regimes

    def add_event(self, event: Any) -> None:
        """A GnssFix, SpeedSample or PowerSample (ingest input)."""
        assert self.ingest is not None, "no track: feed measurements with add_measurement"
        for m in self.ingest.add(event):
            self.add_measurement(m)

    def add_message(self, topic: str, msg: Any) -> None:
        """An input message (rclpy or rosbags) of /gnss/fix, /train/speed or /train/traction_power."""
        if topic == GNSS_TOPIC:
            self.add_event(fix_from_msg(msg))
        elif topic == SPEED_TOPIC:
            self.add_event(speed_from_msg(msg))
        elif topic == POWER_TOPIC:
            self.add_event(power_from_msg(msg))

    def add_measurement(self, m: Measurement) -> None:
        out = self.out
        out.measurements.append(m)
        e = self.estimator.update(m)
        if self.estimator.rejected is not None:  # ukf_node drops it: no estimate, no regime
            # window_calib_node uses it without a regime (from power) once a later one comes, in stamp order
            self._measurements_held.append((m, False))
            self._release_unregimed()
            return
        out.estimates.append(e)
        self._measurements_held.append((m, True))
        self._publish_regimes(self.regimes.push(e, power_state(m, self._power), m))

    def add_measurements(self, measurements: list[Measurement]) -> None:
        """``add_measurement`` for each, stage by stage (every UKF step, then every regime, then the publication in
        add_measurement's order): the same outputs, each stage's code and data staying in the caches (offline).
        (1 Hz run: the chain 120 -> 109 ms against one measurement through every stage at a time.)"""
        estimator = self.estimator
        steps: list[tuple[Measurement, EstimateSample | None]] = []
        for m in measurements:
            e = estimator.update(m)
            steps.append((m, e if estimator.rejected is None else None))  # ukf_node drops a rejected one
        push, power = self.regimes.push, self._power
        triples = [None if e is None else push(e, power_state(m, power), m) for m, e in steps]
        out, held = self.out, self._measurements_held
        for (m, e), published in zip(steps, triples):
            out.measurements.append(m)
            if published is None:  # no estimate: to the window without a regime once a later one comes
                held.append((m, False))
                self._release_unregimed()
                continue
            out.estimates.append(e)  # type: ignore[arg-type]
            held.append((m, True))
            self._publish_regimes(published)

    def _publish_regimes(self, triples: list[tuple[EstimateSample, int, int]]) -> None:
        """What regime_node publishes, then what feature_node and window_calib_node do with each sample's phase
        (the paper's regime notion, which the features and the window method are built on)."""
        out = self.out
        held, features, window = self._measurements_held, self.features, self.window
        for e, regime, phase in triples:
            m, _ = held.popleft()  # e's measurement (those without an estimate went before)
            out.regimes.append(
                RegimeRecord(
                    e.stamp_ns, e.run_id, regime, e.s, e.v, e.effort, e.acceleration, e.v_measured, e.effort_source,
                    phase,
                )
            )  # fmt: skip
            published = features.update(e, phase)
            if published:
                out.features += published
            if window is not None:
                self._window(m, phase)
            if held and not held[0][1]:
                self._release_unregimed()

    def _release_unregimed(self) -> None:
        """The measurements without an estimate now at the front of the queue go to the window without a regime."""
        held = self._measurements_held
        while held and not held[0][1]:
            self._window(held.popleft()[0], None)

    def _window(self, m: Measurement, regime: int | None) -> None:
        if self.window is not None:
            fit = self.window.update(m, regime)
            if fit is not None:
                self.out.windows.append(fit)

    def end_of_input(self) -> PipelineOutput:
        """What the replay does at the end: the ingest releases held samples, then the run is closed."""
        if self.ingest is not None:
            for m in self.ingest.flush():
                self.add_measurement(m)
        self._publish_regimes(self.regimes.flush())
        self.out.features += self.features.end_of_input()
        self.out.best = whole_run_best(self.out.measurements, self.estimator)
        return self.out


def whole_run_best(measurements: list[Measurement], estimator: ResistanceEstimator) -> CoastFit | None:
    """The whole run's best estimate of r (the coast regression over every coasting stretch, offline), with the
    estimator's train, prior and coast-regression settings; None without measurements."""
    if not measurements:
        return None
    series = MeasurementSeries.from_measurements(measurements)
    settings = CoastSettings.from_config(estimator.config)
    arrays = RunArrays.from_series(series, estimator.train, settings)
    return fit_coasts(arrays, estimator.train, settings, estimator.prior)


def whole_run_regimes(out: PipelineOutput, train: TrainSpec, config: RegimeConfig | None = None) -> list[RegimeRecord]:
    """The run's regimes given the whole run (offline), record for record beside ``out.regimes``: the classifier
    over the published estimates with the inputs regime_node gives it (the traction power's state, s and
    Gamma(s) of each estimate's measurement), ``smooth=True`` (with ``imm``: :mod:`.estimation.regime_imm_smoother`;
    with ``hmm``: forward-backward). The phase stays the published one. Not causal: never what the graph publishes."""
    cfg = config if config is not None else RegimeConfig()
    if not out.estimates:
        return list(out.regimes)
    by_stamp = {(m.stamp_ns, m.run_id): m for m in out.measurements}
    meas = [by_stamp.get((e.stamp_ns, e.run_id)) for e in out.estimates]
    power = PowerEffort(train)
    states = [power_state(m, power) for m in meas]

    def column(values: Iterable[Any]) -> np.ndarray:
        return np.array([np.nan if x is None else x for x in values], dtype=float)

    est = out.estimates
    columns = {name: column(getattr(e, name) for e in est) for name in ESTIMATE_COLUMNS if name != "t"}
    columns["t"] = [e.stamp_ns * 1e-9 for e in est]
    regimes = classify_whole_run(
        columns,
        cfg,
        [-1 if p is None else p for p in states],
        column(None if m is None else m.s for m in meas),
        column(None if m is None else m.track_force_integral for m in meas),
    )
    return [replace(r, regime=int(k)) for r, k in zip(out.regimes, regimes.tolist())]


def bag_messages(bag: str | Path) -> Iterator[tuple[str, Any]]:
    """(topic, decoded rosbags message) of the bag's input topics in log-time order (the replay's order)."""
    for m in iter_bag(bag, INPUT_TOPICS):
        yield m.topic, m.decode()


def run_bag(bag: str | Path, track: Track, train: TrainSpec, **configs: Any) -> PipelineOutput:
    """The whole chain on a bag's inputs, as the graph would run it. The inputs are decoded straight to the
    ingest's records (:func:`cdr_inputs.read_input_events`), or, for a bag that is not plain and well formed,
    through ``bag_messages`` (salvage, rosbags decoding and its errors); both give the same events."""
    p = Pipeline(track, train, **configs)
    events = read_input_events(bag)
    if events is None:
        for topic, msg in bag_messages(bag):
            p.add_message(topic, msg)
    else:
        # the ingest over the whole bag, then the chain over its measurements stage by stage: the same calls in the
        # same order for each part (no part reads from a later one), each part's code and data staying in the caches
        # (a 1 Hz run: 198 -> 183 ms for the ingest first, the chain's stages 120 -> 109 ms); the measurements' track
        # terms in one numpy pass once the bag is ingested (the same floats); nothing reads the GNSS delay estimate;
        # Ingest.add_many: Ingest.add on each event, with the common path of a clean recording written out in one loop
        ingest = p.ingest
        assert ingest is not None
        ingest.skip_delay_estimate()
        ingest.defer_terms()
        measurements = ingest.add_many(events)  # ingest.add on each event, its common path in one loop
        ingest.fill_terms()
        p.add_measurements(measurements)
    return p.end_of_input()


def run_measurements(
    measurements: Iterable[Measurement] | MeasurementSeries, train: TrainSpec, **configs: Any
) -> PipelineOutput:
    """The chain after the ingest, on measurements (e.g. a simulated MeasurementSeries)."""
    p = Pipeline(None, train, **configs)
    for m in measurements:
        p.add_measurement(m)
    return p.end_of_input()


__all__ = [
    "FeatureStream",
    "Pipeline",
    "PipelineOutput",
    "RegimeRecord",
    "bag_messages",
    "classify_estimate",
    "run_bag",
    "run_measurements",
    "whole_run_best",
]
