"""train-calib import: CSV, NMEA 0183 and GPX logs to a bag, bad rows counted, wrong formats refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from logexport import bag_streams, write_csv, write_gpx, write_nmea
from repo_paths import REPO

from train_calib import cli
from train_calib.importers.records import Streams

SOURCE = REPO / "bags" / "intercity_32km_10s_00"


@pytest.fixture(scope="module")
def streams() -> Streams:
    return bag_streams(SOURCE)


def run_import(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(["import", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_csv_round_trip_keeps_every_sample(tmp_path, streams, capsys):
    log = write_csv(streams, tmp_path / "run.csv")
    code, out, err = run_import(capsys, str(log), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    back = bag_streams(tmp_path / "bag")
    np.testing.assert_array_equal(back.speed_t_ns // 1000, streams.speed_t_ns // 1000)
    np.testing.assert_allclose(back.speed_ms, streams.speed_ms, atol=2e-5)  # 1e-4 km/h written
    np.testing.assert_allclose(back.lat, streams.lat, atol=1e-8)
    rows = streams.gnss_t_ns.size + streams.speed_t_ns.size
    assert f"used {rows} of {rows} rows (0 bad)" in out


def test_csv_truncated_rows_and_bad_cells_are_reported_and_skipped(tmp_path, streams, capsys):
    lines = write_csv(streams, tmp_path / "run.csv").read_text().splitlines()
    lines[10] = lines[10].rsplit(",", 2)[0]  # truncated: 2 fields short
    lines[20] = lines[20].replace(",", ",abc,", 1).rsplit(",", 1)[0]  # a word where a number belongs
    lines.append(lines[-1][:7])  # the last line cut short
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "bad.csv"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert f"{tmp_path / 'bad.csv'}:11: truncated row: 2 of 4 fields" in out
    assert f"{tmp_path / 'bad.csv'}:21: column lat: 'abc' is not a number" in out
    assert f"{tmp_path / 'bad.csv'}:{len(lines)}: truncated row: 1 of 4 fields" in out
    rows = len(lines) - 1
    assert f"used {rows - 3} of {rows} rows (3 bad)" in out


def test_csv_missing_column_is_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "a.csv").write_text("time,lat,speed_kmh\n0,52.0,10\n")
    code, _out, err = run_import(capsys, str(tmp_path / "a.csv"), "--out", str(tmp_path / "bag"))
    assert code == 2
    assert (
        err.strip()
        == f"train-calib import: error: {tmp_path / 'a.csv'}: missing column 'lon' (header: time, lat, speed_kmh)"
    )
    assert not (tmp_path / "bag").exists()


def test_csv_unsorted_times_are_sorted_and_said(tmp_path, streams, capsys):
    lines = write_csv(streams, tmp_path / "run.csv").read_text().splitlines()
    body = lines[1:]
    body[40], body[41] = body[41], body[40]
    body[100:103] = body[100:103][::-1]
    (tmp_path / "u.csv").write_text("\n".join([lines[0], *body]) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "u.csv"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert "samples out of time order: sorted" in out
    back = bag_streams(tmp_path / "bag")
    assert np.all(np.diff(back.gnss_t_ns) > 0) and np.all(np.diff(back.speed_t_ns) > 0)
    np.testing.assert_allclose(back.speed_ms, streams.speed_ms, atol=2e-5)


@pytest.mark.parametrize(
    ("scale", "unit", "hint"), [(1 / 3.6, "speed_kmh", "m/s read as km/h"), (3.6, "speed_ms", "km/h read as m/s")]
)
def test_csv_speed_off_by_3_6_is_refused(tmp_path, streams, capsys, scale, unit, hint):
    """The speed column holds m/s under a km/h name (or the reverse): the speeds' distance is 3.6 times off."""
    wrong = Streams(**{**streams.__dict__, "speed_ms": streams.speed_ms * scale})
    write_csv(wrong, tmp_path / "w.csv", speed_kmh=unit == "speed_kmh")
    code, _, err = run_import(capsys, str(tmp_path / "w.csv"), "--out", str(tmp_path / "bag"))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and hint in err, err
    assert not (tmp_path / "bag").exists()
    # declaring the unit fixes it
    fixed = "ms" if unit == "speed_kmh" else "kmh"
    code, out, err = run_import(capsys, str(tmp_path / "w.csv"), "--out", str(tmp_path / "bag"), "--speed-unit", fixed)
    assert code == 0 and "ratio 1.0" in out, out + err


def test_csv_separate_files_at_different_rates_and_mapped_columns(tmp_path, streams, capsys):
    pos = ["ts;latitude;longitude"] + [
        f"{t * 1e-6:.3f};{la:.8f};{lo:.8f}" for t, la, lo in zip(streams.gnss_t_ns, streams.lat, streams.lon)
    ]
    spd = ["ts;v"] + [f"{t * 1e-6:.3f};{v:.5f}" for t, v in zip(streams.speed_t_ns, streams.speed_ms)]
    (tmp_path / "pos.csv").write_text("\n".join(pos) + "\n")
    (tmp_path / "speed.csv").write_text("\n".join(spd) + "\n")
    code, _out, err = run_import(
        capsys, str(tmp_path / "pos.csv"), str(tmp_path / "speed.csv"), "--out", str(tmp_path / "bag"),
        "--columns", "time=ts,lat=latitude,lon=longitude,speed=v", "--speed-unit", "ms", "--time-unit", "ms",
    )  # fmt: skip
    assert code == 0, err
    back = bag_streams(tmp_path / "bag")
    assert back.gnss_t_ns.size == streams.gnss_t_ns.size and back.speed_t_ns.size == streams.speed_t_ns.size
    np.testing.assert_allclose(back.speed_ms, streams.speed_ms, atol=1e-5)


def test_csv_iso_times_need_a_zone(tmp_path, streams, capsys):
    lines = write_csv(streams, tmp_path / "run.csv", iso=True).read_text().splitlines()
    lines[5] = lines[5].replace("Z,", ",", 1)
    (tmp_path / "iso.csv").write_text("\n".join(lines) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "iso.csv"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert ":6: ISO 8601 time" in out and "has no zone" in out
    back = bag_streams(tmp_path / "bag")
    assert back.speed_t_ns.size + back.gnss_t_ns.size == streams.speed_t_ns.size + streams.gnss_t_ns.size - 1


def test_nmea_checksums_truncation_and_no_fix(tmp_path, streams, capsys):
    lines = write_nmea(streams, tmp_path / "run.nmea").read_text().splitlines()
    lines[3] = lines[3][:-2] + ("00" if not lines[3].endswith("00") else "11")  # wrong checksum (a GGA)
    lines[7] = lines[7][:30]  # truncated RMC
    lines[9] = lines[9].replace(",1,08,", ",0,08,")  # GGA without fix (checksum now wrong too: recompute)
    from train_calib.importers.nmea import checksum

    body = lines[9][1 : lines[9].index("*")]
    lines[9] = f"${body}*{checksum(body):02X}"
    (tmp_path / "bad.nmea").write_text("\n".join(lines) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "bad.nmea"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert ":4: wrong checksum" in out
    assert ":8: no checksum (truncated?)" in out
    assert ":10: GGA: GGA fix quality 0 (no fix)" in out
    assert f"used {len(lines) - 3} of {len(lines)} rows (3 bad)" in out
    back = bag_streams(tmp_path / "bag")
    assert back.gnss_t_ns.size == streams.gnss_t_ns.size  # RMC gives the epochs whose GGA was bad
    np.testing.assert_allclose(back.lat, streams.lat, atol=1e-7)


def test_nmea_unsorted_and_unit_error(tmp_path, streams, capsys):
    lines = write_nmea(streams, tmp_path / "run.nmea").read_text().splitlines()
    lines[30:33], lines[33:36] = lines[33:36], lines[30:33]
    (tmp_path / "u.nmea").write_text("\n".join(lines) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "u.nmea"), "--out", str(tmp_path / "bag"))
    assert code == 0 and "samples out of time order: sorted" in out, out + err
    # a logger that writes km/h into RMC's knots field (and VTG's): 1.852 times the distance
    kmh = Streams(**{**streams.__dict__, "speed_ms": streams.speed_ms * 1.852})
    write_nmea(kmh, tmp_path / "k.nmea")
    code, _, err = run_import(capsys, str(tmp_path / "k.nmea"), "--out", str(tmp_path / "bag2"))
    assert code == 2 and "km/h read as knots" in err and len(err.strip().splitlines()) == 1


def test_nmea_without_rmc_and_wrong_format_are_one_line(tmp_path, streams, capsys):
    lines = [ln for ln in write_nmea(streams, tmp_path / "r.nmea").read_text().splitlines() if "RMC" not in ln]
    (tmp_path / "gga.nmea").write_text("\n".join(lines) + "\n")
    code, _, err = run_import(capsys, str(tmp_path / "gga.nmea"), "--out", str(tmp_path / "bag"))
    assert code == 2 and "no valid RMC sentence with a date" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_import(capsys, str(tmp_path / "r.nmea"), "--format", "csv", "--out", str(tmp_path / "bag"))
    assert code == 2
    assert (
        err.strip() == f"train-calib import: error: {tmp_path / 'r.nmea'}: not a CSV file (its content looks like NMEA)"
    )
    write_csv(streams, tmp_path / "c.csv")
    code, _, err = run_import(capsys, str(tmp_path / "c.csv"), "--format", "gpx", "--out", str(tmp_path / "bag"))
    assert code == 2 and "not a GPX file (its content looks like CSV)" in err


def test_gpx_truncated_file_keeps_the_points_before_the_cut(tmp_path, streams, capsys):
    text = write_gpx(streams, tmp_path / "run.gpx").read_text()
    cut = text[: len(text) // 2]
    (tmp_path / "cut.gpx").write_text(cut)
    code, out, err = run_import(capsys, str(tmp_path / "cut.gpx"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert ("XML" in out and "truncated" in out) or "XML broken" in out
    back = bag_streams(tmp_path / "bag")
    assert 0.3 * streams.gnss_t_ns.size < back.gnss_t_ns.size < 0.7 * streams.gnss_t_ns.size


def test_gpx_points_without_time_unsorted_and_derived_speed(tmp_path, streams, capsys):
    lines = write_gpx(streams, tmp_path / "run.gpx", with_speed=False).read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if "<trkpt" in ln)
    lines[first + 5] = lines[first + 5].split("<time>")[0] + "</trkpt>"
    lines[first + 20], lines[first + 21] = lines[first + 21], lines[first + 20]
    (tmp_path / "p.gpx").write_text("\n".join(lines) + "\n")
    code, out, err = run_import(capsys, str(tmp_path / "p.gpx"), "--out", str(tmp_path / "bag"))
    assert code == 0, err
    assert f":{first + 6}: trkpt without <time>" in out
    assert "speed derived from the positions" in out and "out of time order" in out
    back = bag_streams(tmp_path / "bag")
    assert back.gnss_t_ns.size == streams.gnss_t_ns.size - 1
    # derived over 10 s fixes with 4 m noise: moving speeds within 2 m/s of the recorded ones (median)
    v_true = np.interp(back.speed_t_ns, streams.speed_t_ns, streams.speed_ms)
    assert np.median(np.abs(back.speed_ms - v_true)) < 2.0


def test_gpx_speed_in_kmh_is_refused(tmp_path, streams, capsys):
    kmh = Streams(**{**streams.__dict__, "speed_ms": streams.speed_ms * 3.6})
    write_gpx(kmh, tmp_path / "k.gpx")
    code, _, err = run_import(capsys, str(tmp_path / "k.gpx"), "--out", str(tmp_path / "bag"))
    assert code == 2 and "km/h read as m/s" in err and len(err.strip().splitlines()) == 1


def test_garbage_and_missing_files_never_trace(tmp_path, capsys):
    (tmp_path / "x.bin").write_bytes(b"\x00\x01\x02" * 10)
    for argv in (
        [str(tmp_path / "x.bin")],
        [str(tmp_path / "none.csv")],
        [str(tmp_path / "x.bin"), "--format", "nmea"],
    ):
        code, _, err = run_import(capsys, *argv, "--out", str(tmp_path / "bag"))
        assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err


def test_imported_bags_replay_like_the_original(tmp_path, streams, capsys):
    """The pipeline on the imported CSV (all samples) equals the original's; NMEA/GPX (speed at the fixes)
    end within 1 % of r(80 km/h) (measured: 0.02 %, 0.05 %)."""
    from train_calib.paths import track_file, train_file
    from train_calib.pipeline import run_bag
    from train_calib.track import load_track
    from train_calib.train import load_train

    track, train = load_track(track_file("intercity_32km")), load_train(train_file("virm6"))
    v = 80 / 3.6
    ref = run_bag(SOURCE, track, train).final
    r_ref = ref.r0 + ref.r1 * v + ref.r2 * v * v
    for name, writer in (("csv", write_csv), ("nmea", write_nmea), ("gpx", write_gpx)):
        log = writer(streams, tmp_path / f"run.{name}")
        assert run_import(capsys, str(log), "--out", str(tmp_path / name), "--gnss-sigma", "4")[0] == 0
        final = run_bag(tmp_path / name, track, train).final
        r = final.r0 + final.r1 * v + final.r2 * v * v
        assert abs(r / r_ref - 1) < (1e-6 if name == "csv" else 0.01), (name, r, r_ref)


def test_power_columns_and_mixed_formats(tmp_path, streams, capsys):
    """Positions from a GPX logger and speed plus power from the train's CSV recorder: one bag."""
    write_gpx(streams, tmp_path / "pos.gpx")
    rows = ["time,speed_ms,power_consumed_w,power_regenerated_w"]
    rows += [f"{t * 1e-9:.6f},{v:.4f},{1e5 * v:.1f},0" for t, v in zip(streams.speed_t_ns, streams.speed_ms)]
    (tmp_path / "rec.csv").write_text("\n".join(rows) + "\n")
    code, out, err = run_import(
        capsys, str(tmp_path / "pos.gpx"), str(tmp_path / "rec.csv"), "--out", str(tmp_path / "b")
    )
    assert code == 0, err
    back = bag_streams(tmp_path / "b")
    assert back.power_t_ns.size == streams.speed_t_ns.size
    np.testing.assert_allclose(back.consumed_w, 1e5 * streams.speed_ms, atol=0.06)
    assert back.speed_t_ns.size == streams.gnss_t_ns.size + streams.speed_t_ns.size  # GPX speeds and CSV speeds
    assert f"{back.power_t_ns.size} power samples" in out


def test_speed_without_positions_is_one_line(tmp_path, streams, capsys):
    rows = ["time,speed_kmh"] + [f"{t * 1e-9:.3f},{v * 3.6:.2f}" for t, v in zip(streams.speed_t_ns, streams.speed_ms)]
    (tmp_path / "s.csv").write_text("\n".join(rows) + "\n")
    code, _, err = run_import(capsys, str(tmp_path / "s.csv"), "--out", str(tmp_path / "b"))
    assert code == 2 and "no usable position" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()
