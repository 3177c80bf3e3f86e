"""The occupation plots (issue 21): distributions_*.png with y labels and the truth, ranges.png with the truth and
the search bounds. Synthetic calibration results, no simulation."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest

from train_calib.occupation import plots
from train_calib.occupation.compositions import DECISION_NAMES, load_train_types
from train_calib.paths import config_file


@pytest.fixture(scope="module")
def types():
    return load_train_types(config_file("train_types/ic_compositions.yaml"))


def _results(comp: str, types, n: int = 12):
    """n runs whose calibrated values spread over the middle of the bounds; truth 5 % above each."""
    rng = np.random.default_rng(4)
    results, truth = [], {}
    for k in range(n):
        params = {name: float(np.mean(types[comp].bounds[name])) * (1.0 + 0.1 * rng.standard_normal())
                  for name in DECISION_NAMES}  # fmt: skip
        rid = f"{comp}-{k:03d}"
        results.append(SimpleNamespace(run_id=rid, composition=comp, params=params))
        truth[rid] = {"run_id": rid, "composition": comp, **{n_: 1.05 * v for n_, v in params.items()}}
    return results, truth


def test_distributions_have_y_labels_and_the_truth(types):
    results, truth = _results("VIRM4", types)
    fig, axes = plots.build_distribution_figure("VIRM4", results, {}, types["VIRM4"].defaults, truth)
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        assert ax.get_ylabel().startswith("density"), name
        median = [line for line in ax.get_lines() if line.get_gid() == "truth_median"]
        assert len(median) == 1
        expected = np.median([truth[r.run_id][name] for r in results])
        assert median[0].get_xdata()[0] == pytest.approx(expected)
        assert any(p.get_gid() == "truth" for p in ax.patches)  # the truth's step histogram
    plt.close(fig)
    fig, axes = plots.build_distribution_figure("VIRM4", results, {}, types["VIRM4"].defaults, None)
    for ax in axes.ravel():
        assert ax.get_ylabel().startswith("density")
        assert not [line for line in ax.get_lines() if line.get_gid() == "truth_median"]
    plt.close(fig)


def test_ranges_show_the_bounds_and_the_truth(types, tmp_path):
    by_comp, truth = {}, {}
    for comp in ("VIRM4", "ICRm"):
        by_comp[comp], t = _results(comp, types)
        truth.update(t)
    fig, axes = plots.build_ranges_figure(by_comp, types, truth)
    comps = [c for c in types.names if c in by_comp]
    for ax, name in zip(axes.ravel(), DECISION_NAMES):
        assert ax.get_ylabel().startswith(name)
        bounds = sorted({float(line.get_ydata()[0]) for line in ax.get_lines() if line.get_gid() == "bound"})
        assert bounds == pytest.approx(sorted({v for c in comps for v in types[c].bounds[name]}))
        spans = [line.get_ydata() for line in ax.get_lines() if line.get_gid() == "truth"]
        assert len(spans) == len(comps)
        for (low, high), comp in zip(spans, comps):
            true = [truth[r.run_id][name] for r in by_comp[comp]]
            assert (low, high) == pytest.approx((min(true), max(true)))
    plt.close(fig)
    fig, axes = plots.build_ranges_figure(by_comp, types, None)
    assert not [line for ax in axes.ravel() for line in ax.get_lines() if line.get_gid() == "truth"]
    plt.close(fig)
    path = plots.ranges_figure(tmp_path / "ranges.png", by_comp, types, truth)
    assert path.stat().st_size > 20_000
