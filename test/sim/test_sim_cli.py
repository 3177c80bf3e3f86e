"""`train-calib simulate`: writes N bags, refuses bad arguments in one line."""

from __future__ import annotations

import pytest

from train_calib import bagio
from train_calib.cli import main
from train_calib.sim import read_truth


def test_writes_n_bags_with_truth(tmp_path, capsys):
    code = main(
        [
            "simulate",
            "--track",
            "dense_corridor_14km",
            "--train",
            "virm4",
            "--runs",
            "3",
            "--seed",
            "4",
            "--period",
            "5",
            "--power",
            "--power-period",
            "2",
            "--wind",
            "--out",
            str(tmp_path),
            "--dense",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 3
    names = [f"dense_corridor_14km_5s_0{k}" for k in range(3)]
    for name in names:
        bag = tmp_path / name
        assert set(bagio.bag_topics(bag)) == set(bagio.INPUT_TOPICS)
        tf = read_truth(bag)
        assert tf.dense is not None and tf.meta["sensors"]["speed_period_s"] == 5.0
        assert tf.meta["driver"]["wind_amplitude"] >= 0 and tf.meta["summary"]["power_samples"] > 0
    r0 = {read_truth(tmp_path / n).meta["resistance"]["r0"] for n in names}
    assert len(r0) == 3  # every run has its own true resistance
    # run 1 alone, regenerated from its recorded command, is the same run
    cmd = read_truth(tmp_path / names[1]).meta["command"].split()
    assert main([*cmd[1:], "--out", str(tmp_path / "again"), "--quiet"]) == 0
    assert (tmp_path / "again" / f"{names[1]}.truth.csv").read_bytes() == (
        tmp_path / f"{names[1]}.truth.csv"
    ).read_bytes()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--runs", "0"], "--runs: must be at least 1, found 0"),
        (["--period", "0"], "--period: must be within [0.01, 600] s"),
        (["--resistance-spread", "2"], "--resistance-spread: must be within [0, 0.9]"),
        (["--coast-min", "300", "--coast-max", "100"], "--coast-max: must be at least --coast-min"),
        (["--power-period", "1"], "--power-period: needs --power"),
        (["--track", "no_such_track"], "no_such_track: track file not found"),
        (["--stop-station", "Utrecht"], "stop_station: no station named 'Utrecht'"),
        (["--start-time", "yesterday"], "--start-time: 'yesterday' is neither ISO 8601"),
        (["--runs", "two"], "argument --runs: invalid int value: 'two'"),
        (["--style", "sporty"], "argument --style: invalid choice"),
    ],
)
def test_bad_arguments_give_one_line(tmp_path, capsys, args, message):
    try:
        code = main(["simulate", "--out", str(tmp_path), *args])
    except SystemExit as exc:  # argparse's own checks (types, choices) exit from parse_args
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("train-calib simulate: error: ") and message in err, err
    assert not any(tmp_path.iterdir())


def test_existing_output_is_refused(tmp_path, capsys):
    assert main(["simulate", "--out", str(tmp_path), "--quiet", "--minimum-time"]) == 0
    assert main(["simulate", "--out", str(tmp_path), "--quiet"]) == 2
    assert "already exists" in capsys.readouterr().err


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for option in ("--resistance-spread", "--coast-min", "--minimum-time", "--power-period", "--first-index"):
        assert option in out
