"""The hand-made mutations of the mutation test (issue 23): realistic one-line bugs in ingest, features, regimes,
window and occupation, each with the tests that should catch it.

A mutation is (file, the exact old snippet, the new snippet, what the bug is, the tests to run). ``old`` must occur
exactly once in the file (``run.py`` refuses the mutation otherwise, so a refactor that moves the code shows up).
"""

from __future__ import annotations

from typing import NamedTuple


class Mutation(NamedTuple):
    name: str
    """Short id (area and number)."""
    path: str
    """File, relative to the repository root."""
    old: str
    """Exact snippet replaced (must occur once)."""
    new: str
    """Its replacement."""
    description: str
    """The bug it stands for."""
    tests: tuple[str, ...]
    """pytest arguments: the tests of that part."""
    survives: str = ""
    """Why the tests are expected not to kill it (the mutant is no bug); empty: a bug the tests must catch."""


INGEST_TESTS = ("test/test_ingest.py", "test/test_ingest_drops.py", "test/test_ingest_line_ends.py")
FEATURE_TESTS = ("test/estimation/test_features.py", "test/estimation/test_feature_rules.py")
REGIME_TESTS = ("test/estimation/test_regimes.py",)
WINDOW_TESTS = (
    "test/window/test_window_model.py",
    "test/window/test_window_kernel.py",
    "test/window/test_window_fit.py",
)
OCCUPATION_TESTS = ("test/occupation/test_occ_length.py", "test/occupation/test_occ_objective.py")

_INGEST = "train_calib/ingest/"
_FEATURES = "train_calib/estimation/features/"
_REGIMES = "train_calib/estimation/"

MUTATIONS: tuple[Mutation, ...] = (
    # -- ingest (tests through the public Ingest API) ---------------------------------------------------------------
    Mutation("ingest-1", _INGEST + "release.py",
             "            self.stats.drop(SPEED, NO_POSITION)\n            return None",
             "            return None",
             "a speed sample without a position is dropped without being counted (no_position)", INGEST_TESTS),
    Mutation("ingest-2", _INGEST + "release.py",
             "            self.stats.drop(SPEED, REVERSING)\n",
             "",
             "a speed sample while reversing is dropped without being counted (reversing)", INGEST_TESTS),
    Mutation("ingest-3", _INGEST + "front.py",
             "    if v > max_speed:",
             "    if v > 2.0 * max_speed:",
             "max_speed checked at twice its value", INGEST_TESTS),
    Mutation("ingest-4", _INGEST + "front.py",
             "    if sample.consumed < 0.0 or sample.regenerated < 0.0:",
             "    if sample.consumed < 0.0:",
             "a negative regenerated power is accepted", INGEST_TESTS),
    Mutation("ingest-5", _INGEST + "front.py",
             "                self.stats.undrop(SPEED, SPEED_JUMP)\n",
             "",
             "the samples of an accepted speed step stay counted as speed_jump drops", INGEST_TESTS),
    Mutation("ingest-6", _INGEST + "matching.py",
             "        if d_all > cfg.max_cross_track:",
             "        if d_all > 2.0 * cfg.max_cross_track:",
             "max_cross_track checked at twice its value", INGEST_TESTS),
    # the three survivors of the ingest author's own 15 mutations (issue 23's split)
    Mutation("ingest-7", _INGEST + "pairing.py",
             "while len(speeds) > 2 and",
             "while len(speeds) > 1 and",
             "the pairer's trim keeps one validated speed sample, not two (a repeat of the one before is then "
             "counted out_of_order instead of duplicate; no measurement changes)", INGEST_TESTS),
    Mutation("ingest-8", _INGEST + "position.py",
             "            self.s = min(max(self.s, 0.0), length_m)\n",
             "",
             "dead reckoning backwards while reversing is not clamped at the line's ends", INGEST_TESTS),
    Mutation("ingest-9", _INGEST + "odometer_checks.py",
             "            self.delay.reset()\n            # the queue is kept",
             "            self.delay.reset()\n            self.queue.clear()\n            # the queue is kept",
             "the fixes queued for the direction check are dropped when the odometer restarts after a gap (the "
             "reversing count then depends on whether a fix or the speed sample of the restart's stamp came first)",
             INGEST_TESTS),
    # -- features ---------------------------------------------------------------------------------------------------
    Mutation("features-1", _FEATURES + "rules.py",
             "    return t - first_t >= 0.98 * window - 1e-6",
             "    return t - first_t >= 1.5 * window - 1e-6",
             "brake samples count only 1.5 brake windows into the braking", FEATURE_TESTS),
    Mutation("features-2", _FEATURES + "rules.py",
             "    return (regime == TRACTION) & (accel > 0.0)",
             "    return (regime != BRAKING) & (accel > 0.0)",
             "max effort and power also from cruising and coasting steps", FEATURE_TESTS),
    Mutation("features-3", _FEATURES + "rules.py",
             "    return (v_mid >= cfg.max_power_window_low) & (v_mid <= cfg.max_power_window_high)",
             "    return (v_mid >= cfg.max_effort_window_low) & (v_mid <= cfg.max_power_window_high)",
             "the power window starts at the effort window's low end", FEATURE_TESTS),
    Mutation("features-4", _FEATURES + "rules.py",
             "    return mean_u, mean_u - slope * mean_v, slope",
             "    return mean_u, mean_u + slope * mean_v, slope",
             "the effort line's intercept with the wrong sign", FEATURE_TESTS),
    Mutation("features-5", _FEATURES + "rules.py",
             "    return _NAN if src in KNOWN_ZERO_EFFORT else effort - accel",
             "    return _NAN if src in KNOWN_ZERO_EFFORT else effort + accel",
             "w = r + g of a coasting step with the acceleration's sign flipped (hold test)", FEATURE_TESTS),
    Mutation("features-6", _FEATURES + "rules.py",
             "        return i, (i >= 0) & (i == self.index(v - accel * _longer(window, dt)))",
             "        return i, (i >= 0) & (i == self.index(v + accel * _longer(window, dt)))",
             "the speed-step test looks at the speed a window ahead instead of back", FEATURE_TESTS),
    Mutation("features-7", _FEATURES + "rules.py",
             "    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])",
             "    return float(values[order][np.searchsorted(cw, 0.25 * cw[-1])])",
             "the cruise speed at the lower quartile instead of the median", FEATURE_TESTS),
    Mutation("features-8", _FEATURES + "final_phases.py",
             "                if gap <= self._merge_gap and not self._braked_since(ph, r):",
             "                if gap <= self._merge_gap:",
             "a coast is continued across braking", FEATURE_TESTS),
    Mutation("features-9", _FEATURES + "brake_rates.py",
             "        std = math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else _NAN",
             "        std = math.sqrt(self.m2 / self.n) if self.n > 1 else _NAN",
             "the online brake rate std is the population std", FEATURE_TESTS),
    Mutation("features-10", _FEATURES + "online.py",
             "            self._cruise_dt.append(max(dt, 0.0))",
             "            self._cruise_dt.append(1.0)",
             "online cruise speed weighted per sample instead of per second", FEATURE_TESTS),
    # -- regimes ----------------------------------------------------------------------------------------------------
    Mutation("regimes-1", _REGIMES + "regime_model.py",
             "    if abs(a) <= tol_a:",
             "    if abs(a) < 0.5 * tol_a:",
             "the rule's cruise tolerance halved", REGIME_TESTS),
    Mutation("regimes-2", _REGIMES + "regime_model.py",
             "        best = BRAKING",
             "        best = COASTING",
             "the most probable regime reports coasting for braking", REGIME_TESTS),
    Mutation("regimes-3", _REGIMES + "regime_model.py",
             "START_PRIOR = (0.85, 0.05, 0.05, 0.05)",
             "START_PRIOR = (0.25, 0.25, 0.25, 0.25)",
             "the HMM starts without the departing prior", REGIME_TESTS),
    Mutation("regimes-4", _REGIMES + "regime_imm.py",
             "_NOISE_FLOOR = 0.2",
             "_NOISE_FLOOR = 2.0",
             "the IMM's noise floor ten times too high", REGIME_TESTS),
    Mutation("regimes-5", _REGIMES + "regimes_batch.py",
             "    w_last = np.where(seen, diff[np.maximum(last, 0)], DEFAULT_W)",
             "    w_last = np.where(seen, diff[np.maximum(last, 0)], 0.0)",
             "the whole-run HMM assumes r + g = 0 before the first computed effort", REGIME_TESTS),
    # -- window -----------------------------------------------------------------------------------------------------
    Mutation("window-1", "train_calib/window/model.py",
             "        wheel = (self.eta * consumed if consumed > 0.0 else 0.0) - power_regenerated / self.eta",
             "        wheel = (self.eta * consumed if consumed > 0.0 else 0.0) + power_regenerated / self.eta",
             "regenerated power adds to the tractive force (streaming step model)", WINDOW_TESTS),
    Mutation("window-2", "train_calib/window/model.py",
             "    c2 = v * v * (1.0 + train.tunnel_factor * tau)",
             "    c2 = v * v",
             "the tunnel factor left out of the difference rows", WINDOW_TESTS),
    Mutation("window-3", "train_calib/window/fit.py",
             "    if speed_span < config.min_speed_span:",
             "    if speed_span < 0.1 * config.min_speed_span:",
             "a window of nearly constant speed counts as well posed", WINDOW_TESTS),
    Mutation("window-4", "train_calib/physics.py",
             "    return 0.161 + 7.5 / (3.6 * v + 44.0)",
             "    return 0.161 + 7.5 / (3.6 * v + 4.4)",
             "Curtius-Kniffler adhesion with a wrong constant (eq. 6)", WINDOW_TESTS),
    Mutation("window-5", "train_calib/window/_kernel.c",
             ".c0 = p[SP_C0],",
             ".c0 = p[SP_C2],",
             "the C kernel reads the max power where the max effort belongs (a reordered step model)", WINDOW_TESTS),
    Mutation("window-6", "train_calib/window/model.py",
             '            "c2": self.c2,',
             '            "c2": self.c0,',
             "the Python side gives the kernel c0 under the name c2", WINDOW_TESTS),
    # -- occupation -------------------------------------------------------------------------------------------------
    Mutation("occupation-1", "train_calib/occupation/length.py",
             "        low_m=np.maximum(v * (d_rel[k] - delta_s), 0.0),",
             "        low_m=np.maximum(v * (d_rel[k] + delta_s), 0.0),",
             "the length interval's low end with the wrong sign of delta (eq. 2)", OCCUPATION_TESTS),
    Mutation("occupation-2", "train_calib/occupation/length.py",
             "    ok &= np.where(ok, v, 0.0) >= min_speed_ms",
             "    ok &= np.where(ok, v, 0.0) >= 0.0",
             "joints near a stop (speed below min_speed) are used", OCCUPATION_TESTS),
    Mutation("occupation-3", "train_calib/occupation/objective.py",
             "        total += float(np.sum(np.abs(r - shift)))",
             "        total += float(np.sum(r - shift))",
             "the objective sums signed instead of absolute errors (eq. 8)", OCCUPATION_TESTS),
    Mutation("occupation-4", "train_calib/occupation/objective.py",
             "            part = np.sum(np.abs(r - np.median(r, axis=1, keepdims=True)), axis=1)",
             "            part = np.sum(np.abs(r - np.mean(r, axis=1, keepdims=True)), axis=1)",
             "the batch objective's free departure by the mean, not the median", OCCUPATION_TESTS),
)  # fmt: skip
