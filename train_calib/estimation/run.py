"""Whole-run API: the filter over a MeasurementSeries, the resistance filter's own trajectory, and the offline
unscented RTS smoother."""

from __future__ import annotations

import numpy as np

from ..measurement import MeasurementSeries
from ..train import Davis, TrainSpec
from .config import UKFConfig
from .covariance import UPPER_INDEX, unpack
from .records import EFFORT_COMPUTED, HEALTH_RESET, EstimateSeries
from .safeguards import SafeguardConfig
from .ukf import ResistanceEstimator, StepInput, StepResult, running_resistance


def estimate_run(
    series: MeasurementSeries,
    train: TrainSpec,
    config: UKFConfig | None = None,
    initial: Davis | None = None,
    estimator: ResistanceEstimator | None = None,
    safeguards: SafeguardConfig | None = None,
) -> EstimateSeries:
    """Run the UKF over every sample; identical numbers to ``ResistanceEstimator.update`` per sample.

    ``estimator`` continues an existing filter (its config and state); otherwise a new one is made.
    Several run_ids in the series are handled as the node does (``carry_over``).
    """
    est = estimator if estimator is not None else ResistanceEstimator(train, config, initial, safeguards)
    n = len(series)
    out = EstimateSeries.empty(n)
    cols = (
        series.stamp_ns.tolist(),
        series.run_id.tolist(),
        series.s.tolist(),
        series.v.tolist(),
        series.track_force.tolist(),
        series.s_measured.tolist(),
        series.s_variance.tolist(),
        series.v_variance.tolist(),
        series.power_valid.tolist(),
        series.power_consumed.tolist(),
        series.power_regenerated.tolist(),
        series.tunnel_fraction.tolist(),
        series.track_force_integral.tolist(),
    )
    process = est.process
    rows = [process(StepInput(*args)) for args in zip(*cols)]
    if n:
        table = np.array([row[:-1] for row in rows], dtype=float)  # every field but the packed covariance
        packed = np.array([row.covariance for row in rows], dtype=float)
        out.stamp_ns[:] = series.stamp_ns
        out.run_id[:] = series.run_id
        out.s[:], out.v[:], out.r0[:], out.r1[:], out.r2[:] = table[:, 0:5].T
        out.effort[:], out.acceleration[:], out.resistance[:], out.track_force[:], out.nis[:] = table[:, 5:10].T
        source = table[:, StepResult._fields.index("effort_source")]
        out.effort_known[:] = source != EFFORT_COMPUTED
        out.effort_source[:] = source
        out.health[:] = table[:, StepResult._fields.index("health")]
        out.dt[:] = table[:, StepResult._fields.index("dt")]
        out.input_effort[:] = table[:, StepResult._fields.index("input_effort")]
        out.decoupled[:] = table[:, StepResult._fields.index("decoupled")] != 0.0
        out.v_measured[:] = series.v
        out.covariance[:] = packed[:, UPPER_INDEX]
    return out


def resistance_run(
    series: MeasurementSeries,
    train: TrainSpec,
    config: UKFConfig | None = None,
    initial: Davis | None = None,
    safeguards: SafeguardConfig | None = None,
) -> tuple[EstimateSeries, EstimateSeries]:
    """(published estimates, the resistance filter's own trajectory) over the run.

    With look-ahead (``exploit_known``, ``coast_confirm_ahead`` > 0) the resistance filter runs behind the
    published estimate (ResistanceEstimator): its trajectory is one UKF over every sample, with the effort it
    used on each step (``input_effort``, ``decoupled``, ``effort_known``), flushed at the end of the series. Row
    k is the filter after sample k; s, v, r, covariance, resistance, input_effort, dt, decoupled, effort_known,
    health are its own, the other fields the published ones. Without look-ahead the two are the same series.
    """
    est = ResistanceEstimator(train, config, initial, safeguards)
    if not est.has_lookahead:
        pub = estimate_run(series, train, estimator=est)
        return pub, pub
    trace = est.record_trace()
    pub = estimate_run(series, train, estimator=est)
    est.flush()
    out = pub.select(np.arange(len(pub)))
    n = len(out)
    filled = np.zeros(n, dtype=bool)
    state = out.state.copy()
    packed = np.empty((n, 15))
    for step in trace:
        k = step.arrival - 1  # arrivals count update() calls from 1: one per sample of the series
        state[k] = step.x
        packed[k] = step.covariance
        out.input_effort[k], out.dt[k], out.track_force[k] = step.input_effort, step.dt, step.track_force
        out.decoupled[k], out.effort_known[k], out.health[k] = step.decoupled, step.effort_known, step.health
        filled[k] = True
    for k in range(n):  # samples the filter did not use (rejected): its state stays, no step
        if not filled[k]:
            if k > 0:
                state[k], packed[k] = state[k - 1], packed[k - 1]
            out.dt[k], out.effort_known[k], out.decoupled[k] = 0.0, False, False
    out.s[:], out.v[:], out.r0[:], out.r1[:], out.r2[:] = state.T
    out.covariance[:] = packed[:, UPPER_INDEX]
    out.resistance[:] = running_resistance(out.r0, out.r1, out.r2, out.v)
    return pub, out


def smooth_run(
    series: MeasurementSeries,
    train: TrainSpec,
    config: UKFConfig | None = None,
    initial: Davis | None = None,
    estimates: EstimateSeries | None = None,
) -> EstimateSeries:
    """Offline unscented Rauch-Tung-Striebel smoother (Sarkka 2008) over the resistance filter's run.

    The backward pass reuses each forward step's input (effort u, track force g, dt, decoupling) and
    the same closed-form unscented transform; the chain is cut at run starts, gaps and resets. The forward
    pass is the resistance filter's trajectory (``resistance_run``: with look-ahead it runs behind the published
    estimate). Returns a copy of ``estimates`` (the published ones; computed when not given) with s, v, r0, r1,
    r2, covariance and resistance smoothed (r clipped at 0); effort, acceleration, nis, health and the rest stay
    the published values.
    """
    est = ResistanceEstimator(train, config, initial)
    pub, fwd = resistance_run(series, train, config, initial)
    out = (estimates if estimates is not None else pub).select(np.arange(len(fwd)))
    n = len(fwd)
    if n < 2:
        return out
    xs = fwd.state.copy()
    ps = fwd.covariance.copy()
    iu = np.triu_indices(5)
    for k in range(n - 2, -1, -1):
        dt = float(fwd.dt[k + 1])
        if dt <= 0.0 or fwd.run_id[k + 1] != fwd.run_id[k] or fwd.health[k + 1] == HEALTH_RESET:
            continue
        xk = fwd.state[k]
        pk = fwd.covariance[k]
        u, g, decoupled = float(fwd.input_effort[k + 1]), float(fwd.track_force[k]), bool(fwd.decoupled[k + 1])
        pred = est.predict(tuple(float(v) for v in xk), tuple(float(v) for v in pk[iu]), dt, u, g, decoupled)
        if pred is None:
            continue
        x_bar = np.array(pred.x)
        p_bar = unpack(pred.covariance)
        m = np.array(pred.m)
        b = np.array([0.5 * dt * dt, dt, 0.0, 0.0, 0.0])
        cross = pk.copy()
        cross[:, 0] += dt * pk[:, 1]  # P A^T
        cross += np.outer(m, b)
        try:
            gain = np.linalg.solve(p_bar.T, cross.T).T  # C P_bar^-1
        except np.linalg.LinAlgError:
            continue
        xs[k] = xk + gain @ (xs[k + 1] - x_bar)
        pk_s = pk + gain @ (ps[k + 1] - p_bar) @ gain.T
        ps[k] = 0.5 * (pk_s + pk_s.T)
    xs[:, 1:] = np.maximum(xs[:, 1:], 0.0)
    out.s[:], out.v[:], out.r0[:], out.r1[:], out.r2[:] = xs.T
    out.covariance[:] = ps
    out.resistance[:] = running_resistance(out.r0, out.r1, out.r2, out.v)
    if not np.all(np.isfinite(xs)):
        raise FloatingPointError("smoother produced non-finite states")
    return out
