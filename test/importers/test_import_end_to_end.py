"""End to end on the real TTOBench profiles: a run of the independent simulator (../shared/validation/runs) exported
to CSV, NMEA and GPX, imported, a track built from the imported GNSS and the TTOBench track JSON, replayed with the
TTOBench train JSON. r(v_ref) (v_ref = min(80 km/h, 0.8 v_max)) against the original bag's replay on its own
track and train files.

Measured (final = best on these runs):

| profile | original | built track, CSV / NMEA / GPX | truth |
|---|---|---|---|
| CH Stadelhofen (4 stops, 1 Hz) | 0.04145 | -4.55 / -4.57 / -4.55 % | 0.03918 |
| SE Vasteras (2 stops, 2 s GNSS) | 0.04732 | 0.00 % each | 0.03623 |
| CN Yizhuang (14 stops, 1 Hz) | 0.04659 | -1.66 / -1.65 / -1.66 % | 0.04379 |

The format costs under 0.1 %; the rest is the built track against the synthesised geometry of the original, whose
chainage differs from its chord length by 0.2 % (on Stadelhofen the built track's estimate is the nearer to the
truth). Bounds: 6 % against the original, 0.3 % between formats.
"""

from __future__ import annotations

import json

import pytest
from logexport import bag_streams, write_csv, write_gpx, write_nmea
from repo_paths import REPO

from train_calib import cli
from train_calib.pipeline import run_bag
from train_calib.track import load_track
from train_calib.train import load_train

VALIDATION = REPO.parent / "shared" / "validation"
CASES = [
    ("stadelhofen_kiss_eco_1hz_00", "stadelhofen", "kiss", "CH_Stadelhofen_Altstetten", "CH_Stadler_KISS"),
    ("vasteras_kiss_pi_1hz_00", "vasteras", "kiss", "SE_Vasteras_Kolback", "CH_Stadler_KISS"),
    ("yizhuang_metro_eco_1hz_00", "yizhuang", "metro", "CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway"),
]
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not (VALIDATION / "runs").is_dir(), reason="../shared/validation not present"),
]


def r_at(e, v: float) -> float:
    return e.r0 + e.r1 * v + e.r2 * v * v


@pytest.mark.parametrize(("bag", "line", "train", "track_json", "train_json"), CASES)
def test_exported_imported_built_replayed(tmp_path, capsys, bag, line, train, track_json, train_json):
    runs = VALIDATION / "runs"
    track = load_track(runs / f"track_{line}.yaml")
    v_ref = min(80.0 / 3.6, 0.8 * float(track.speed_limit.values.max()))
    original = run_bag(runs / bag, track, load_train(runs / f"train_{train}.yaml"))
    r_orig = r_at(original.final, v_ref)
    truth = json.loads((runs / f"{bag}.validation-truth.json").read_text())
    r_true = truth["r0"] + truth["r1"] * v_ref + truth["r2"] * v_ref**2
    streams = bag_streams(runs / bag)
    tto_train = load_train(VALIDATION / "ttobench" / "trains" / f"{train_json}.json")
    results = {}
    for fmt, writer in (("csv", write_csv), ("nmea", write_nmea), ("gpx", write_gpx)):
        log = writer(streams, tmp_path / f"log.{fmt}")
        out = tmp_path / fmt
        assert cli.main(["import", str(log), "--out", str(out / "bag"), "--gnss-sigma", "4"]) == 0
        assert "(0 bad)" in capsys.readouterr().out
        profile = VALIDATION / "ttobench" / "tracks" / f"{track_json}.json"
        assert cli.main(["build-track", "--gnss", str(out / "bag"), "--profile", str(profile), "--name", line,
                         "--out", str(out / "track.yaml"), "--margin", "0"]) == 0  # fmt: skip
        built = load_track(out / "track.yaml")
        assert len(built.stations) == len(track.stations)
        result = run_bag(out / "bag", built, tto_train)
        results[fmt] = (r_at(result.final, v_ref), r_at(result.best, v_ref))
    for fmt, (final, best) in results.items():
        assert final == pytest.approx(r_orig, rel=0.06), (fmt, final, r_orig)
        assert best == pytest.approx(r_at(original.best, v_ref), rel=0.06), (fmt, best)
        assert final == pytest.approx(results["csv"][0], rel=3e-3), fmt
        # no worse against the truth than the original replay, by more than 5 % of r
        assert abs(final / r_true - 1) <= abs(r_orig / r_true - 1) + 0.05
