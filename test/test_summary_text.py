"""The printed summary (summary_text.format_summary) says what the outputs hold: the configuration, r(v) with sigma on
board and over the whole run, and for the window calibration what was published (issue 21: it said "nothing
published" while every window message was there, ill-posed)."""

from __future__ import annotations

from train_calib.summary_text import format_summary

POOLED = {"r0": 0.01, "r1": 1e-4, "r2": 4e-5, "covariance": [[1e-6, 0, 0], [0, 1e-10, 0], [0, 0, 1e-12]], "windows": 9}
ROW = {"value": 0.03, "std": 0.002, "manufacturer": 0.025}
COEFF = {"value": 0.01, "std": 0.001, "manufacturer": 0.01, "vs_manufacturer": 0.0}


def _summary(**window):
    return {
        "ukf_preset": "learning",
        "final": {"run_id": 0, "r0": COEFF, "r1": COEFF, "r2": COEFF, "resistance_at_kmh": {"80": ROW}},
        "best": {"resistance_at_kmh": {"80": ROW}, "learnt": False, "coasting_stretches": 0, "coasting_s": 0.0},
        "window": {"gof": "rmse", "window_length_s": 60.0, "messages": 1227, "well_posed": 0, **window},
    }


def test_ill_posed_windows_are_reported_as_published_with_the_pooled_curve():
    text = format_summary(_summary(last_well_posed=None, pooled=POOLED))
    assert "nothing published" not in text
    assert "every one of the 1227 published windows has r0, r1, r2 NaN" in text
    assert "pooled over 9 windows, r(v) N/kg: 40 km/h" in text


def test_configuration_and_r_of_v_with_sigma_and_the_prior_said():
    text = format_summary(_summary(last_well_posed=None, pooled=None))
    assert "Configuration: ukf preset learning" in text
    assert "on board (last message): 80 km/h 0.0300 +- 0.0020 (+20.0 % vs manuf.)" in text
    assert "no coasting stretch found: the estimate is the train file's values with the prior's sigma" in text


def test_the_count_of_coasting_stretches_is_said_in_the_right_number():
    summary = _summary(last_well_posed=None, pooled=None)
    summary["best"].update(learnt=True, coasting_stretches=1, coasting_s=16.0)
    assert "learnt from 1 coasting stretch (16 s)" in format_summary(summary)
    summary["best"].update(coasting_stretches=2, coasting_s=100.0)
    assert "learnt from 2 coasting stretches (100 s)" in format_summary(summary)
