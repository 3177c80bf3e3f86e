"""Never a traceback: seeded mutations of CSV, NMEA and GPX logs (characters flipped, inserted, deleted, files cut)
end with exit 0 (the bad rows listed) or exit 2 with one line. 1,500 cases tried while writing the readers (two
bugs found: a ROS stamp's int32 seconds overflowing, a carriage return inside a CSV field); 150 here."""

from __future__ import annotations

import random

import pytest
from logexport import bag_streams, write_csv, write_gpx, write_nmea
from repo_paths import REPO

from train_calib import cli

ALPHABET = ',;$*<>\n\r0123456789.-abcNSEWAV"\x00 \t'


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    folder = tmp_path_factory.mktemp("src")
    streams = bag_streams(REPO / "bags" / "intercity_32km_10s_00")
    return {f: w(streams, folder / f"src.{f}").read_text() for f, w in
            (("csv", write_csv), ("nmea", write_nmea), ("gpx", write_gpx))}  # fmt: skip


def mutate(text: str, rng: random.Random) -> str:
    chars = list(text)
    for _ in range(rng.randint(1, 30)):
        i = rng.randrange(len(chars))
        op = rng.random()
        if op < 0.4:
            chars[i] = rng.choice(ALPHABET)
        elif op < 0.7:
            del chars[i]
        else:
            chars.insert(i, rng.choice(",;$*\n9-."))
    if rng.random() < 0.2:
        chars = chars[: rng.randrange(len(chars))]
    return "".join(chars)


def test_mutated_logs_never_trace(sources, tmp_path, capsys):
    rng = random.Random(20261125)
    codes = {0: 0, 2: 0}
    for k in range(150):
        fmt = rng.choice(sorted(sources))
        path = tmp_path / f"f{k}.{fmt}"
        path.write_text(mutate(sources[fmt], rng))
        extra = ["--format", fmt] if rng.random() < 0.5 else []
        code = cli.main(["import", str(path), "--out", str(tmp_path / f"b{k}"), *extra])
        err = capsys.readouterr().err.strip()
        assert code in (0, 2), (k, code, err)
        codes[code] += 1
        if code == 2:
            assert len(err.splitlines()) == 1 and "Traceback" not in err, (k, err)
            assert not (tmp_path / f"b{k}").exists()
    assert codes[0] > 50  # most mutations cost a few rows, not the import
