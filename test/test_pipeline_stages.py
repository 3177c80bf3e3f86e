"""run_bag's offline order (the ingest over the whole bag, then the chain stage by stage: Pipeline.add_measurements)
publishes exactly what one sample at a time through every part publishes (Pipeline.add_event / add_measurement, the
nodes' order): every output, bit for bit, also with measurements the UKF rejects and with the window calibration."""

from __future__ import annotations

import dataclasses

from repo_paths import REPO, bench_module

from train_calib.cdr_inputs import read_input_events
from train_calib.paths import track_file, train_file
from train_calib.pipeline import Pipeline, run_bag
from train_calib.track import load_track
from train_calib.train import load_train


def _digest_module():
    """bench/refactor/output_digest.py (the refactors' exact encoding of every output), loaded by path."""
    return bench_module("refactor/output_digest.py", "refactor_output_digest")


BAG = REPO / "bags" / "tunnel_line_37km_1s_00"  # 1 Hz with traction power: the window calibration fits


def _outputs(out) -> dict[str, str]:
    names = ("measurements", "estimates", "regimes", "features", "windows", "best", "ingest_stats")
    digest = _digest_module().digest
    return {name: digest(getattr(out, name)) for name in names}


def test_run_bag_equals_one_sample_at_a_time() -> None:
    track, train = load_track(track_file("tunnel_line_37km")), load_train(train_file("icrm"))
    online = Pipeline(track, train)
    for event in read_input_events(BAG):
        online.add_event(event)
    reference = online.end_of_input()
    assert len(reference.windows) > 1000
    assert _outputs(run_bag(BAG, track, train)) == _outputs(reference)


def test_add_measurements_with_rejected_ones_equals_add_measurement() -> None:
    track, train = load_track(track_file("tunnel_line_37km")), load_train(train_file("icrm"))
    measurements = run_bag(BAG, track, train, window=False).measurements
    for k in (100, 101, 500, 900):  # the UKF rejects a negative speed: no estimate, the window gets it unregimed
        measurements[k] = dataclasses.replace(measurements[k], v=-1.0)
    one_by_one = Pipeline(None, train)
    for m in measurements:
        one_by_one.add_measurement(m)
    staged = Pipeline(None, train)
    staged.add_measurements(measurements)
    a, b = one_by_one.end_of_input(), staged.end_of_input()
    assert len(a.estimates) == len(measurements) - 4
    assert _outputs(a) == _outputs(b)
