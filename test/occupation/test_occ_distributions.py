"""Maximum-likelihood fits and KS selection, against closed forms, scipy's own fits and known samples."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from train_calib.occupation.distributions import CANDIDATES, best_fit, fit_all, fit_distribution


def _ks_by_hand(x: np.ndarray, cdf) -> float:
    """sup |F_n - F| from the order statistics (independent of scipy.stats.kstest)."""
    x = np.sort(x)
    n = x.size
    f = cdf(x)
    return float(max(np.max(np.arange(1, n + 1) / n - f), np.max(f - np.arange(n) / n)))


def test_closed_forms_are_the_mle():
    rng = np.random.default_rng(11)
    x = rng.lognormal(mean=-3.0, sigma=0.3, size=200)
    normal = fit_distribution(x, "normal")
    assert normal.params == pytest.approx({"loc": np.mean(x), "scale": np.std(x)}, rel=1e-12)
    lognormal = fit_distribution(x, "lognormal")
    assert lognormal.params["s"] == pytest.approx(np.std(np.log(x)), rel=1e-12)
    assert lognormal.params["scale"] == pytest.approx(np.exp(np.mean(np.log(x))), rel=1e-12)
    uniform = fit_distribution(x, "uniform")
    assert uniform.params == pytest.approx({"loc": x.min(), "scale": np.ptp(x)}, rel=1e-12)
    # Pareto (loc 0): no numerical optimiser finds a higher likelihood than the closed form
    pareto = fit_distribution(x, "pareto")
    b, loc, scale = stats.pareto.fit(x, floc=0.0)
    assert pareto.log_likelihood >= np.sum(stats.pareto.logpdf(x, b, loc, scale)) - 1e-9
    assert pareto.params["scale"] == pytest.approx(x.min())


def test_numerical_fits_match_scipy_and_recover_truth():
    rng = np.random.default_rng(5)
    x = stats.weibull_min(3.0, scale=0.45).rvs(400, random_state=rng)
    w = fit_distribution(x, "weibull")
    c, _, scale = stats.weibull_min.fit(x, floc=0.0)
    assert w.params["c"] == pytest.approx(c, rel=1e-3) and w.params["scale"] == pytest.approx(scale, rel=1e-3)
    assert w.params["c"] == pytest.approx(3.0, rel=0.12)
    # tiny magnitudes (r2 ~ 4e-5) fit as well as large ones
    g = fit_distribution(stats.genextreme(-0.2, loc=3.5e-5, scale=4e-6).rvs(3000, random_state=rng), "gev")
    assert g.params["c"] == pytest.approx(-0.2, abs=0.05)
    assert g.params["loc"] == pytest.approx(3.5e-5, rel=0.02) and g.params["scale"] == pytest.approx(4e-6, rel=0.05)
    j = fit_distribution(stats.johnsonsb(-0.7, 0.7, loc=0.79, scale=0.23).rvs(3000, random_state=rng), "johnsonsb")
    assert j.params["a"] == pytest.approx(-0.7, abs=0.12) and j.params["b"] == pytest.approx(0.7, rel=0.12)
    ll = fit_distribution(stats.fisk(6.0, scale=0.5).rvs(2000, random_state=rng), "loglogistic")
    assert ll.params["c"] == pytest.approx(6.0, rel=0.06) and ll.params["scale"] == pytest.approx(0.5, rel=0.02)


def test_ks_statistic_and_p_value():
    rng = np.random.default_rng(2)
    x = rng.normal(6.2, 0.8, 70)
    for fit in fit_all(x):
        assert fit.ok, fit.message
        assert fit.ks_statistic == pytest.approx(_ks_by_hand(x, fit.frozen.cdf), abs=1e-12)
        assert 0.0 <= fit.p_value <= 1.0
        assert np.isfinite(fit.aic)


@pytest.mark.parametrize(
    ("name", "frozen"),
    [
        ("uniform", stats.uniform(0.014, 0.002)),
        ("normal", stats.norm(6.2, 0.8)),
        ("pareto", stats.pareto(3.0, scale=3.5e-5)),
        ("gev", stats.genextreme(0.5, loc=0.8, scale=0.1)),
    ],
)
def test_selection_prefers_the_generating_family(name, frozen):
    x = frozen.rvs(500, random_state=np.random.default_rng(9))
    fits = {f.name: f for f in fit_all(x)}
    best = min(f.ks_statistic for f in fits.values() if f.ok)
    # the true family is (within sampling noise) the best; a clearly wrong one is far worse
    assert fits[name].ks_statistic <= best + 0.015
    assert fits[name].p_value > 0.05
    assert max(f.ks_statistic for f in fits.values() if f.ok) > best + 0.05
    assert best_fit(x).ks_statistic == best


def test_bad_samples_are_reported_not_raised():
    assert not fit_distribution([1.0, 2.0], "normal").ok
    flat = fit_distribution([0.66] * 10, "weibull")
    assert not flat.ok and "degenerate" in flat.message
    neg = fit_distribution([-1.0, 0.5, 2.0, 3.0], "lognormal")
    assert not neg.ok and "positive" in neg.message
    assert fit_distribution([-1.0, 0.5, 2.0, 3.0], "normal").ok
    ranked = fit_all([-1.0, 0.5, 2.0, 3.0, 2.5])
    assert [f.ok for f in ranked] == sorted([f.ok for f in ranked], reverse=True)  # failures last
    assert {f.name for f in ranked} == set(CANDIDATES)
    with pytest.raises(ValueError):
        fit_distribution([1, 2, 3], "cauchy")
