"""Maximum-likelihood fits of candidate distributions, chosen by the Kolmogorov-Smirnov statistic.

Besinovic et al. (2013, Figs. 7-9, Table 4) fit each calibrated parameter of a composition with
the candidate distributions and keep the one with the lowest KS statistic, reporting its
parameters, the KS statistic and the p-value. Candidates and their parametrisation (scipy.stats
names; the positive-support families in their classic two-parameter form with location 0, as
MATLAB's ``fitdist`` and EasyFit fit them):

=============  ================  ===========================================  =================
name           scipy             parameters                                   MLE
=============  ================  ===========================================  =================
weibull        weibull_min       c (shape), scale; loc = 0                    numerical
gev            genextreme        c (shape), loc, scale                        numerical, 2 starts
uniform        uniform           loc = min, scale = max - min                 closed form
pareto         pareto            b (shape), scale = min; loc = 0              closed form
loglogistic    fisk              c (shape), scale; loc = 0                    numerical
johnsonsb      johnsonsb         a, b (shapes), loc, scale (support bounds)   numerical, 2 starts
normal         norm              loc (mean), scale (std, ddof 0)              closed form
lognormal      lognorm           s (sigma of log), scale = exp(mu); loc = 0   closed form
=============  ================  ===========================================  =================

Numerical fits run on data divided by their mean (location-scale families: standardised), then
map back, so tiny parameters like r2 ~ 4e-5 fit as well as large ones. The p-value is the
one-sample KS test's against the fitted distribution; with parameters estimated from the same
data it is optimistic (Lilliefors), as in the paper — use it to rank, not as a significance level.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

CANDIDATES: tuple[str, ...] = (
    "weibull",
    "gev",
    "uniform",
    "pareto",
    "loglogistic",
    "johnsonsb",
    "normal",
    "lognormal",
)
SCIPY_NAMES = {
    "weibull": "weibull_min",
    "gev": "genextreme",
    "uniform": "uniform",
    "pareto": "pareto",
    "loglogistic": "fisk",
    "johnsonsb": "johnsonsb",
    "normal": "norm",
    "lognormal": "lognorm",
}
POSITIVE_ONLY = frozenset({"weibull", "pareto", "loglogistic", "lognormal"})


@dataclass
class FitResult:
    """One candidate fitted to one sample."""

    name: str  # our candidate name (see CANDIDATES)
    scipy_name: str
    params: dict[str, float] = field(default_factory=dict)  # shape(s), loc, scale in scipy's order
    ks_statistic: float = math.nan
    p_value: float = math.nan
    log_likelihood: float = math.nan
    aic: float = math.nan
    n: int = 0
    ok: bool = False
    message: str = ""

    @property
    def frozen(self):
        """The fitted scipy frozen distribution."""
        return getattr(stats, self.scipy_name)(**self.params)

    def describe(self, digits: int = 4) -> str:
        """``weibull(c=3.1, loc=0, scale=0.42)``."""
        inner = ", ".join(f"{k}={_fmt(v, digits)}" for k, v in self.params.items())
        return f"{self.name}({inner})"


def fit_distribution(data: Sequence[float], name: str) -> FitResult:
    """Maximum-likelihood fit of candidate ``name`` with KS statistic, p-value, log-likelihood and AIC."""
    if name not in SCIPY_NAMES:
        raise ValueError(f"unknown distribution {name!r} (known: {', '.join(CANDIDATES)})")
    x = np.asarray(data, dtype=float)
    x = x[np.isfinite(x)]
    result = FitResult(name, SCIPY_NAMES[name], n=int(x.size))
    if x.size < 3:
        result.message = f"needs at least 3 values, got {x.size}"
        return result
    if np.ptp(x) <= 1e-12 * max(1.0, float(np.max(np.abs(x)))):
        result.message = "all values equal (degenerate sample)"
        return result
    if name in POSITIVE_ONLY and np.min(x) <= 0:
        result.message = "needs positive values"
        return result
    dist = getattr(stats, result.scipy_name)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        try:
            params = _FITTERS[name](x)
        except Exception as exc:  # scipy optimisers raise a variety of errors on bad samples
            result.message = f"fit failed: {type(exc).__name__}: {exc}"
            return result
        frozen = dist(**params)
        loglik = float(np.sum(frozen.logpdf(x)))
        if not math.isfinite(loglik):
            result.message = "fit gives zero density at some values"
            result.params = params
            return result
        ks = stats.kstest(x, frozen.cdf)
    result.params = params
    result.ks_statistic = float(ks.statistic)
    result.p_value = float(ks.pvalue)
    result.log_likelihood = loglik
    result.aic = 2.0 * len(_free[name]) - 2.0 * loglik
    result.ok = True
    return result


def fit_all(data: Sequence[float], candidates: Sequence[str] = CANDIDATES) -> list[FitResult]:
    """Every candidate fitted; successful fits first, by increasing KS statistic."""
    fits = [fit_distribution(data, name) for name in candidates]
    return sorted(fits, key=lambda f: (not f.ok, f.ks_statistic if f.ok else math.inf))


def best_fit(data: Sequence[float], candidates: Sequence[str] = CANDIDATES) -> FitResult:
    """The candidate with the lowest KS statistic (``ok`` False if none could be fitted)."""
    return fit_all(data, candidates)[0]


# -- the fitters: each returns scipy keyword parameters on the original scale ------------------

_free = {
    "weibull": ("c", "scale"),
    "gev": ("c", "loc", "scale"),
    "uniform": ("loc", "scale"),
    "pareto": ("b", "scale"),
    "loglogistic": ("c", "scale"),
    "johnsonsb": ("a", "b", "loc", "scale"),
    "normal": ("loc", "scale"),
    "lognormal": ("s", "scale"),
}


def _fit_uniform(x: np.ndarray) -> dict[str, float]:
    lo, hi = float(np.min(x)), float(np.max(x))
    return {"loc": lo, "scale": hi - lo}


def _fit_normal(x: np.ndarray) -> dict[str, float]:
    return {"loc": float(np.mean(x)), "scale": float(np.std(x))}


def _fit_lognormal(x: np.ndarray) -> dict[str, float]:
    logs = np.log(x)
    return {"s": float(np.std(logs)), "loc": 0.0, "scale": float(np.exp(np.mean(logs)))}


def _fit_pareto(x: np.ndarray) -> dict[str, float]:
    x_m = float(np.min(x))
    total = float(np.sum(np.log(x / x_m)))
    return {"b": x.size / total, "loc": 0.0, "scale": x_m}


def _fit_scaled_loc0(scipy_name: str, shape: str):
    """Two-parameter (shape, scale) fit with loc = 0 on x / mean(x)."""

    def fit(x: np.ndarray) -> dict[str, float]:
        m = float(np.mean(x))
        c, _, scale = getattr(stats, scipy_name).fit(x / m, floc=0.0)
        return {shape: float(c), "loc": 0.0, "scale": float(scale) * m}

    return fit


def _gev_start(z: np.ndarray) -> tuple[float, ...]:
    """(c, loc, scale) from L-moments (Hosking et al. 1985); scipy's c is Hosking's k."""
    x = np.sort(z)
    n = x.size
    i = np.arange(n)
    b0 = x.mean()
    b1 = np.sum(i * x) / (n * (n - 1))
    b2 = np.sum(i * (i - 1) * x) / (n * (n - 1) * (n - 2))
    l1, l2, l3 = b0, 2 * b1 - b0, 6 * b2 - 6 * b1 + b0
    t3 = l3 / l2
    zz = 2.0 / (3.0 + t3) - math.log(2.0) / math.log(3.0)
    c = float(np.clip(7.8590 * zz + 2.9554 * zz * zz, -0.9, 0.9))
    if abs(c) < 1e-6:
        c = 1e-6
    g = math.gamma(1.0 + c)
    scale = l2 * c / ((1.0 - 2.0**-c) * g)
    loc = l1 - scale * (1.0 - g) / c
    return (c, loc, scale)


def _johnsonsb_start(z: np.ndarray) -> tuple[float, ...]:
    """(a, b, loc, scale): support a little wider than the data, a and b from the logit transform."""
    pad = 0.05 * float(np.ptp(z))
    loc, scale = float(np.min(z)) - pad, float(np.ptp(z)) + 2.0 * pad
    u = (z - loc) / scale
    y = np.log(u / (1.0 - u))
    sd = float(np.std(y))
    return (-float(np.mean(y)) / sd, 1.0 / sd, loc, scale)


def _best_of_starts(scipy_name: str, names: tuple[str, ...], start_fn):
    """Full fit on standardised data from scipy's default start and a moment-based one; best likelihood wins."""

    def fit(x: np.ndarray) -> dict[str, float]:
        m, s = float(np.mean(x)), float(np.std(x))
        z = (x - m) / s
        dist = getattr(stats, scipy_name)
        guess = start_fn(z)
        k = len(names)
        attempts = [{}, {"args": guess[:k], "loc": guess[k], "scale": guess[k + 1]}]
        best, best_ll = None, -math.inf
        for a in attempts:
            try:
                p = dist.fit(z, *a.get("args", ()), **{key: a[key] for key in ("loc", "scale") if key in a})
            except Exception:
                continue
            ll = float(np.sum(dist.logpdf(z, *p)))
            if math.isfinite(ll) and ll > best_ll:
                best, best_ll = p, ll
        if best is None:
            raise RuntimeError("no starting point converged")
        out = {key: float(v) for key, v in zip(names, best[:-2])}
        out["loc"] = m + s * float(best[-2])
        out["scale"] = s * float(best[-1])
        return out

    return fit


_FITTERS = {
    "weibull": _fit_scaled_loc0("weibull_min", "c"),
    "gev": _best_of_starts("genextreme", ("c",), _gev_start),
    "uniform": _fit_uniform,
    "pareto": _fit_pareto,
    "loglogistic": _fit_scaled_loc0("fisk", "c"),
    "johnsonsb": _best_of_starts("johnsonsb", ("a", "b"), _johnsonsb_start),
    "normal": _fit_normal,
    "lognormal": _fit_lognormal,
}


def _fmt(value: float, digits: int) -> str:
    return f"{value:.{digits}g}"
