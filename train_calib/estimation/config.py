"""Configuration of the estimator core: UKF, regime recognition and feature extraction (frozen ParamSets).

``UKFConfig()`` (preset ``learning``) is Cunillera et al. (2022), Table 1, for the filter of s and v, with the
resistance learnt by the coast regression (``resistance_learning``); ``UKFConfig.paper()`` is Table 1 with r in the
UKF state and every engineering option off where the paper is silent (computed effort on every step, Euler
process, no process noise). ``UKFConfig.converging()``
is the measured alternative that converges from a wrong prior (docs/estimator.md, "Presets").
Units are SI; speeds in m/s (the paper's km/h values are converted in the defaults).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

from ..errors import ConfigError
from ..params import ParamSet, param
from ..physics import KMH

EFFORT_MODES = ("computed", "exploit_known")
INTEGRATIONS = ("euler", "midpoint")
NONNEGATIVE_RULES = ("project", "clip")
CARRY_OVER = ("reset", "keep")
PRESETS = ("learning", "paper", "converging")
RESISTANCE_LEARNING = ("coast_regression", "ukf")
REGIME_METHODS = ("imm", "hmm", "rule")


@dataclass(frozen=True)
class UKFConfig(ParamSet):
    """Resistance UKF over x = (s, v, r0, r1, r2); Table 1 for s and v, r learnt from the coasting by default."""

    # -- Table 1 -------------------------------------------------------------------------------
    alpha: float = param(0.001, "van der Merwe sigma-point spread alpha (Table 1)", low=0.0, high=1.0, low_open=True)
    beta: float = param(2.0, "van der Merwe prior-knowledge parameter beta (Table 1)", low=0.0)
    kappa: float = param(-2.0, "van der Merwe secondary scaling kappa (Table 1); L + kappa must be > 0", low=-4.9)
    init_std_s: float = param(1.0, "initial standard deviation of s (Table 1)", unit="m", low=0.0, low_open=True)
    init_std_v: float = param(
        0.0018 * KMH, "initial standard deviation of v (Table 1: 0.0018 km/h)", unit="m/s", low=0.0, low_open=True
    )
    init_std_r0: float = param(1e-6, "initial standard deviation of r0 (Table 1)", unit="N/kg", low=0.0, low_open=True)
    init_std_r1: float = param(
        1e-8, "initial standard deviation of r1 (Table 1)", unit="N/(kg m/s)", low=0.0, low_open=True
    )
    init_std_r2: float = param(
        1e-9, "initial standard deviation of r2 (Table 1)", unit="N/(kg (m/s)^2)", low=0.0, low_open=True
    )
    init_std_r_relative: float = param(
        0.0,
        "initial std of each r_j is at least this fraction of its prior value (0: the absolute values only)",
        low=0.0,
        high=10.0,
    )
    meas_std_s: float = param(4.0, "position measurement noise std (paper: 4 m)", unit="m", low=0.0, low_open=True)
    meas_std_v: float = param(
        1.0 * KMH, "speed measurement noise std (paper: 1 km/h)", unit="m/s", low=0.0, low_open=True
    )
    use_measurement_variance: bool = param(
        False, "take R from each measurement's s_variance / v_variance instead of meas_std_s / meas_std_v"
    )
    # -- process ---------------------------------------------------------------------------------
    integration: str = param(
        "euler",
        "euler: a at the start of the step (paper eq. 4-5); midpoint: a at the predicted mid-step speed (RK2)",
        choices=INTEGRATIONS,
    )
    accel_noise_std: float = param(
        0.0,
        "std of a piecewise-constant acceleration disturbance per step (Q = q b b^T, b = (dt^2/2, dt)); paper: 0",
        unit="m/s^2",
        low=0.0,
    )
    noise_r0: float = param(0.0, "random-walk std of r0 per sqrt(s); paper: 0 (harmful)", unit="N/kg/sqrt(s)", low=0.0)
    noise_r1: float = param(0.0, "random-walk std of r1 per sqrt(s)", unit="N/(kg m/s)/sqrt(s)", low=0.0)
    noise_r2: float = param(0.0, "random-walk std of r2 per sqrt(s)", unit="N/(kg (m/s)^2)/sqrt(s)", low=0.0)
    update_uses_process_noise: bool = param(
        True,
        "true: the gain sees Q (sigma points redrawn after Q is added); false: the propagated sigma points as in "
        "Cunillera eq. 12-15 and filterpy (identical when Q = 0)",
    )
    # -- applied effort ----------------------------------------------------------------------------
    effort_mode: str = param(
        "computed",
        "computed: u from consecutive speeds with the latest estimate on every step (paper); exploit_known: u = 0 "
        "on confirmed coasting steps and u from measured traction power where valid, computed otherwise",
        choices=EFFORT_MODES,
    )
    use_power: bool = param(
        True, "exploit_known: use traction power (power_valid) for the effort: f_t = eta (P - P_aux) / (v gamma m)"
    )
    decouple_unknown_effort: bool = param(
        False,
        "on computed-effort steps the resistance sigma points do not enter the process (the speed change was used to "
        "compute u, so it says nothing about r): r is then only learnt from known-effort steps",
    )
    coast_effort_tolerance: float = param(
        0.025, "|computed effort| within this is taken as coasting (u = 0 known)", unit="N/kg", low=0.0
    )
    coast_confirm_time: float = param(
        20.0,
        "exploit_known: u = 0 is taken as known when the effort from a linear fit of the measured speeds over this "
        "(covered) window lies in the coasting band",
        unit="s",
        low=0.0,
    )
    coast_confirm_ahead: float = param(
        10.0,
        "exploit_known: a coasting step informs the resistance only when the confirmation also holds on the windows "
        "ending at every sample up to this long after it (a traction ramp that starts inside the step shows only "
        "later; after a hole in the speeds a window shorter than half coast_confirm_time is not tested); the "
        "resistance filter, which learns r, runs this far behind the latest measurement and an output filter brings "
        "s and v to it, so the published r lags by this much (docs/estimator.md); 0: past samples only, one filter",
        unit="s",
        low=0.0,
        high=600.0,
    )
    coast_max_residual: float = param(
        0.3,
        "known coasting also needs the measured speeds of the confirmation window to lie on a straight line within "
        "this standard deviation (no traction or brake change inside the window)",
        unit="m/s",
        low=0.0,
        low_open=True,
    )
    coast_reference: str = param(
        "prior",
        "resistance used to compute the effort for the known-coasting decision: prior (fixed: no feedback from a "
        "drifting estimate into the decision) or estimate (latest r)",
        choices=("prior", "estimate"),
    )
    coast_vs_hold: bool = param(
        True,
        "known coasting also needs the computed effort nearer 0 (coasting) than r + g (holding the speed, a = 0): the "
        "band is cut at (r + g) / 2 on that side; a low-speed hold has an effort inside the coasting band",
    )
    known_effort_gate: float = param(
        0.999,
        "a known-effort step whose speed innovation exceeds this chi-square quantile (1 dof) is redone with the "
        "computed effort (1: no gate)",
        low=0.5,
        high=1.0,
    )
    known_effort_min_speed: float = param(
        3.0, "known effort is used only when both ends of the step are faster than this", unit="m/s", low=0.0
    )
    power_threshold: float = param(
        0.005, "wheel power per effective mass below this counts as no traction", unit="W/kg", low=0.0
    )
    power_coasting: bool = param(
        True,
        "use_power: a step with neither traction nor regenerated power at both ends and no clear braking in the "
        "speeds is coasting (u = 0 known). False where braking need not show in the power (no electric brake, or a "
        "meter that reports no regeneration): such steps are then coasting only where the speeds confirm it",
    )
    accel_window: float = param(
        10.0,
        "the published acceleration is the slope of a causal linear fit of the measured speed over this window "
        "(always at least the last two samples: at 10 s sampling the paper's two-point difference)",
        unit="s",
        low=0.0,
        high=600.0,
    )
    # -- how r is learnt (docs/estimator.md, "Coast regression") ----------------------------------
    resistance_learning: str = param(
        "coast_regression",
        "coast_regression: r from a Bayesian regression over the coasting stretches detected in the data (the UKF "
        "tracks s and v, r a consider parameter); ukf: r in the UKF state as in the paper (presets paper, converging)",
        choices=RESISTANCE_LEARNING,
    )
    prior_scale_std: float = param(
        0.18,
        "coast_regression: prior std of a scale common to r0, r1, r2 (the train file's curve 10-30 % off)",
        low=0.0,
        high=5.0,
    )
    prior_coefficient_std: float = param(
        0.10, "coast_regression: prior std of each coefficient on its own, relative", low=0.0, high=5.0
    )
    coast_ratio_min: float = param(
        0.4, "coast_regression: coasting when -(a + g) is at least this fraction of the train file's r(v)", low=0.0
    )
    coast_ratio_max: float = param(2.5, "coast_regression: ... and at most this fraction", low=0.0, low_open=True)
    coast_hold_sigmas: float = param(
        3.0, "coast_regression: coasting needs |a| at least this many standard errors from 0 (not a hold)", low=0.0
    )
    coast_slope_precision: float = param(
        0.2,
        "coast_regression: the speed slope's window is long enough for a standard error of this fraction of r",
        low=0.01,
        high=10.0,
    )
    coast_window_min: float = param(10.0, "coast_regression: shortest slope window", unit="s", low=1.0, high=600.0)
    coast_window_samples: float = param(
        4.0, "coast_regression: slope window at least this many sample periods", low=2.0, high=100.0
    )
    coast_min_duration: float = param(
        12.0, "coast_regression: shortest stretch used, after trimming (and at least 3 periods)", unit="s", low=0.0
    )
    coast_stretch_std: float = param(
        0.03,
        "coast_regression: std of an error common to a stretch, relative to r (grade, curves, light effort)",
        low=0.0,
        high=10.0,
    )
    coast_min_speed: float = param(5.0, "coast_regression: no coasting below this speed", unit="m/s", low=0.0)
    coast_energy_period: float = param(
        5.0,
        "coast_regression: at this sample interval and longer, coasts are found and fitted in the energy form "
        "(v^2/2 + the track force's integral over s; docs/estimator.md, 'Coasts at 10 s sampling'), shorter ones in "
        "the time form",
        unit="s",
        low=0.0,
    )
    coast_energy_window: int = param(
        4, "coast_regression, energy form: samples in one window of the coasting test", low=3, high=50
    )
    coast_energy_end_effort: float = param(
        0.5,
        "coast_regression, energy form: a coast starts and ends between two samples, so each end sample of a stretch "
        "and its outer neighbour may hold an effort in their step; that effort's std over the whole step (a leaked "
        "sample's energy std: this x v x the period). Each configuration of the ends is weighed by its evidence; 0 "
        "takes the detected ends as sure",
        unit="N/kg",
        low=0.0,
    )
    coast_energy_grade_error: float = param(
        0.1,
        "coast_regression: the energy form needs the gradient to change within the steps: the median over the "
        "moving steps of |mean g over the step - the trapezoid of g at its ends| at least this fraction of r",
        low=0.0,
    )
    # -- safeguards and health -----------------------------------------------------------------
    nonnegative: str = param(
        "project",
        "keep v, r0, r1, r2 >= 0: project (covariance-weighted projection onto the active bounds, then clip) or clip",
        choices=NONNEGATIVE_RULES,
    )
    repair_min_eigenvalue: float = param(
        1e-9,
        "repair of a non-positive-definite covariance: floor on the eigenvalues of its correlation matrix",
        low=0.0,
        low_open=True,
        high=0.1,
    )
    nis_window: int = param(20, "steps in the normalised-innovation-squared window for health", low=1, high=100000)
    nis_quantile: float = param(
        0.999,
        "DEGRADED when the NIS summed over the window exceeds this chi-square quantile",
        low=0.5,
        high=1.0,
        low_open=True,
    )
    max_dt: float = param(
        120.0,
        "a longer gap re-initialises s and v from the measurement (keeps r); health RESET",
        unit="s",
        low=0.0,
        low_open=True,
    )
    carry_over: str = param(
        "reset",
        "at a new run_id: reset (r and P from the prior, paper) or keep (r and P_rr carried over)",
        choices=CARRY_OVER,
    )
    carry_over_inflation: float = param(1.0, "keep: the carried r covariance is multiplied by this", low=1.0, high=1e6)

    STATE_SIZE = 5

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        if self.alpha**2 * (self.STATE_SIZE + self.kappa) <= 0.0:
            raise ConfigError(source, f"{prefix}kappa", f"L + kappa must be > 0 (L = 5), found kappa {self.kappa:g}")

    @property
    def lam(self) -> float:
        """van der Merwe lambda = alpha^2 (L + kappa) - L."""
        return self.alpha**2 * (self.STATE_SIZE + self.kappa) - self.STATE_SIZE

    @classmethod
    def learning(cls, **overrides: Any) -> UKFConfig:
        """The defaults: Table 1's filter for s and v, r from the coasting stretches (coast regression) with the
        train file's values as an honest prior (about 19 % std of r(v))."""
        return cls().replace(**overrides) if overrides else cls()

    @classmethod
    def paper(cls, **overrides: Any) -> UKFConfig:
        """Cunillera et al. (2022) Table 1 with computed effort: r in the UKF state, which keeps the prior."""
        base = cls(resistance_learning="ukf")
        return base.replace(**overrides) if overrides else base

    @classmethod
    def converging(cls, **overrides: Any) -> UKFConfig:
        """Measured alternative that converges from a +-20 % wrong prior (docs/estimator.md, Presets).

        Prior std 30 % of each manufacturer value; u = 0 taken as known on coasting steps confirmed over
        40 s and u from traction power where measured; r a consider parameter on computed-effort steps;
        midpoint process; an acceleration disturbance of 0.01 m/s^2; well-conditioned sigma points
        (alpha 0.5, kappa 0); initial std of v 0.3 m/s and of s 4 m (the measurement's).
        """
        base = cls(
            alpha=0.5,
            beta=2.0,
            kappa=0.0,
            init_std_v=0.3,
            init_std_s=4.0,
            init_std_r_relative=0.3,
            integration="midpoint",
            accel_noise_std=0.01,
            effort_mode="exploit_known",
            decouple_unknown_effort=True,
            coast_confirm_time=40.0,
            resistance_learning="ukf",
        )
        return base.replace(**overrides) if overrides else base

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> UKFConfig:
        """A named preset ('learning', 'paper' or 'converging') with optional overrides."""
        if name not in PRESETS:
            raise ConfigError("UKFConfig", "preset", f"{name!r} is not one of {', '.join(PRESETS)}")
        return getattr(cls, name)(**overrides)


@dataclass(frozen=True)
class RegimeConfig(ParamSet):
    """Driving regime recognition (Cunillera et al. 2022, Section 3.2; docs/estimator.md, "Regimes")."""

    method: str = param(
        "imm",
        "imm: the regime of each sample, physical (traction u > 0 beyond holding, coasting u = 0, braking, cruising = "
        "holding the speed), from an interacting multiple-model filter on the measured speeds, with the paper's phase "
        "(hmm) beside it; hmm: forward filter of a hidden Markov model over the four regimes on the acceleration each "
        "predicts, the paper's phases (traction/coast cycles around a target are cruising); rule: the paper's "
        "per-sample thresholds (effort_tolerance, cruise_tolerance)",
        choices=REGIME_METHODS,
    )
    imm_speed_noise_std: float = param(
        0.15,
        "imm: standard deviation of a measured speed about the true one (0.5 km/h noise, 1 km/h rounding: 0.16)",
        unit="m/s",
        low=0.001,
        high=10.0,
    )
    imm_adapt_noise: bool = param(
        True,
        "imm: learn the speed noise over the run from the second differences of the measured speeds, starting from "
        "imm_speed_noise_std (never below a fifth of it)",
    )
    imm_hold_accel_std: float = param(
        0.005, "imm: standard deviation of the acceleration while the speed is held", unit="m/s^2", low=1e-4, high=1.0
    )
    imm_coast_accel_std: float = param(
        0.02,
        "imm: standard deviation of the coasting deceleration about -(r + g), added to resistance_rel_std x (r + g)",
        unit="m/s^2",
        low=1e-4,
        high=1.0,
    )
    imm_accel_walk_std: float = param(
        0.05,
        "imm: traction and braking: the acceleration walks randomly by this much in one second",
        unit="m/s^2",
        low=1e-4,
        high=5.0,
    )
    imm_mean_dwell: float = param(
        40.0,
        "imm: mean duration of a regime: the probability of a change between samples dt apart is 1 - exp(-dt / this)",
        unit="s",
        low=0.1,
        high=1e5,
    )
    imm_switch_max: float = param(
        0.3,
        "imm: at most this probability of a change between two samples (long sample periods)",
        low=0.0,
        high=0.75,
        low_open=True,
    )
    imm_standstill_speed: float = param(
        0.25,
        "imm: a sample whose measured speed (the filtered one where none) is slower is standing (UNKNOWN) for the "
        "regime and restarts the imm; below standstill_speed (which the phase keeps) so that the first step of speeds "
        "rounded to 1 km/h (0.28 m/s), a departure or the end of a stop, is moving",
        unit="m/s",
        low=0.0,
    )
    effort_tolerance: float = param(
        0.025, "rule: |effort| within this is coasting; above traction, below braking", unit="N/kg", low=0.0
    )
    cruise_tolerance: float = param(
        0.06, "rule: traction or braking with |acceleration| within this is cruising", unit="m/s^2", low=0.0
    )
    standstill_speed: float = param(
        0.3, "when the speed is given: slower samples are UNKNOWN (standing; not a regime)", unit="m/s", low=0.0
    )
    hold_detection: bool = param(
        False,
        "rule: a sample in the coasting band whose acceleration is nearer 0 than the coasting deceleration "
        "(|a| < |effort|, effort - a = r + g) is CRUISING: a speed hold whose effort r + g lies inside the band "
        "(low speed)",
    )
    accel_noise_std: float = param(
        0.025,
        "hmm: standard deviation of the published acceleration about the value its regime predicts (10 s two-point "
        "differences of speeds rounded to 1 km/h: 0.023)",
        unit="m/s^2",
        low=0.001,
        high=1.0,
    )
    switch_probability: float = param(
        0.1,
        "hmm: prior probability that the regime changes between two consecutive samples (to any other alike)",
        low=0.0,
        high=0.75,
        low_open=True,
    )
    traction_accel_mean: float = param(
        0.07,
        "hmm: mean net acceleration in traction (exponential prior: small values near the target speed, large at low "
        "speed)",
        unit="m/s^2",
        low=0.001,
        high=5.0,
    )
    traction_accel_min: float = param(
        0.02,
        "hmm: traction accelerates at least this much (the exponential prior starts here)",
        unit="m/s^2",
        low=0.0,
        high=1.0,
    )
    brake_decel_min: float = param(0.1, "hmm: braking decelerates at least this much", unit="m/s^2", low=0.0, high=5.0)
    brake_decel_max: float = param(1.0, "hmm: braking decelerates at most this much", unit="m/s^2", low=0.01, high=5.0)
    known_coast_odds: float = param(
        10.0,
        "hmm: an effort of exactly 0 is the estimator's known coasting (u = 0 confirmed, effort_mode exploit_known): "
        "it multiplies the odds of COASTING against each other regime by this (1: ignored)",
        low=1.0,
        high=1e6,
    )
    resistance_rel_std: float = param(
        0.3,
        "hmm and imm: relative uncertainty of r + g (the coasting deceleration): adds (this x (r + g))^2 to the "
        "variance of the COASTING prediction",
        low=0.0,
        high=2.0,
    )
    resistance_shape_speed: float = param(
        20.0,
        "hmm: r + g is carried over samples with a known zero effort as r(v) ~ v_c^2 + v^2 with this v_c "
        "(sqrt(r0 / r2): VIRM 19, ICRm 26)",
        unit="m/s",
        low=0.1,
        high=1000.0,
    )
    lag_samples: int = param(
        1,
        "1 publishes each sample's regime when the next sample has come, given that one too (one sample period "
        "later, stamped with its own time; a fixed-lag smoother of one sample: hmm the phase, imm the regime, and "
        "the regime at the sample's instant where a change fell inside a step of >= 5 s); 0 publishes it at once "
        "(causal: eco driving at 10 s 81.9 % of samples right against 91.1 %, docs/estimator.md)",
        low=0,
        high=1,
    )

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        if not self.brake_decel_min < self.brake_decel_max:
            raise ConfigError(
                source, f"{prefix}brake_decel_max", f"must be greater than brake_decel_min ({self.brake_decel_min:g})"
            )


@dataclass(frozen=True)
class FeatureConfig(ParamSet):
    """Feature extraction (Cunillera et al. 2022, Sections 3.3, 4.3-4.4); windows and steps per network."""

    max_effort_window_low: float = param(10.0 * KMH, "max tractive effort fit window, low end", unit="m/s", low=0.0)
    max_effort_window_high: float = param(30.0 * KMH, "max tractive effort fit window, high end", unit="m/s", low=0.0)
    max_power_window_low: float = param(50.0 * KMH, "max tractive power window, low end", unit="m/s", low=0.0)
    max_power_window_high: float = param(130.0 * KMH, "max tractive power window, high end", unit="m/s", low=0.0)
    brake_step_edges: tuple[float, ...] = param(
        (0.0, 40.0 * KMH, 60.0 * KMH, 80.0 * KMH, 130.0 * KMH),
        "lower bounds of the brake-rate speed steps, ascending; the last step is open above (ATB-EG: 0, 40, 60, 80, "
        "130 km/h)",
        unit="m/s",
        low=0.0,
    )
    standstill_speed: float = param(
        0.3, "steps whose mean speed is below this are standing time (regime UNKNOWN, not a phase)", unit="m/s", low=0.0
    )
    brake_window: float = param(
        10.0,
        "a braking sample counts for the brake rates only when braking has lasted this long before it and its speed "
        "over this window stayed in one step (the estimator's accel_window: the acceleration is a window average)",
        unit="s",
        low=0.0,
    )
    cruise_min_duration: float = param(
        30.0, "cruising phases shorter than this are not listed in cruise_speeds", unit="s", low=0.0
    )
    phase_merge_gap: float = param(
        10.0,
        "final coast/brake: an interruption by another regime no longer than this is merged into the phase (label "
        "noise)",
        unit="s",
        low=0.0,
    )
    final_coast_min_duration: float = param(
        60.0,
        "final coast: the last coasting phase (after merging) with at least this much time labelled coasting; shorter "
        "ones are transition or noise fragments, or a low-speed hold before the stop brake read as coasting (the "
        "papers' final coasts last 2.5-10 min)",
        unit="s",
        low=0.0,
    )
    final_brake_min_duration: float = param(
        0.0,
        "final brake: the last braking phase (after merging) with at least this much time labelled braking",
        unit="s",
        low=0.0,
    )
    boundary_refinement: bool = param(
        True,
        "final coast/brake: locate the start and end of the phase between samples, at the break of a continuous "
        "two-segment line fitted to the speed around the labelled change, and the end of the final brake where the "
        "speed of its last samples extrapolates to zero; the brake rates count a braking run's samples up to its "
        "end located so (the labels end a brake late) (false: changes at the middle of the step where the label "
        "changes)",
    )
    boundary_window: float = param(
        10.0,
        "boundary refinement: speed samples used on each side of a change, at least three sample periods (longer "
        "windows see the curvature of a coasting speed)",
        unit="s",
        low=0.0,
        high=600.0,
    )
    boundary_search: float = param(
        15.0,
        "boundary refinement: the change is searched from this long (at least two sample periods) before the first "
        "sample labelled with the new regime up to it (the recogniser's latency)",
        unit="s",
        low=0.0,
        high=600.0,
    )
    boundary_from_power: bool = param(
        True,
        "boundary refinement: where the effort sources show the start or end of a coast (measured traction power "
        "ending before it or starting after it, electric braking starting after it), the change lies between the "
        "two samples where the power changed: the middle of that step (of two steps: the speed break within them); "
        "a coast is not merged across measured traction",
    )
    hold_check_window: float = param(
        120.0,
        "final coast: the speeds of the last this-many seconds of a coasting phase are checked for a hold at its end "
        "(a low-speed hold has its effort inside the coasting band: cut off, see boundary_refinement)",
        unit="s",
        low=0.0,
        high=3600.0,
    )
    hold_check_min: float = param(
        20.0, "final coast: a hold at its end is looked for when it lasts at least this long", unit="s", low=0.0
    )
    histogram_bins: int = param(10, "bins of the fleet histograms", low=1, high=1000)

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        for name in ("max_effort_window", "max_power_window"):
            low, high = getattr(self, f"{name}_low"), getattr(self, f"{name}_high")
            if not low < high:
                raise ConfigError(source, f"{prefix}{name}_high", f"must be greater than {name}_low ({low:g} m/s)")
        edges = self.brake_step_edges
        if len(edges) == 0 or any(b <= a for a, b in itertools.pairwise(edges)):
            raise ConfigError(source, f"{prefix}brake_step_edges", "expected a non-empty strictly ascending list")
