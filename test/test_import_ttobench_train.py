"""TTOBench train JSON: --train reads it directly (kN -> N/kg of effective mass), convert-train writes the YAML."""

from __future__ import annotations

import json

import pytest
from repo_paths import REPO

from train_calib import cli
from train_calib.errors import ConfigError
from train_calib.train import load_train

TTO = REPO.parent / "shared" / "validation" / "ttobench" / "trains"
RUNS = REPO.parent / "shared" / "validation" / "runs"
PAIRS = [("CH_Stadler_KISS", "train_kiss"), ("00_Loco_Dyn", "train_loco"), ("CN_Beijing_Subway", "train_metro")]
pytestmark = pytest.mark.skipif(not TTO.is_dir(), reason="../shared/validation/ttobench not present")


@pytest.mark.parametrize(("json_name", "yaml_name"), PAIRS)
def test_json_matches_the_independent_conversion(json_name, yaml_name):
    """The validation runs' YAMLs were converted by another team: Davis, effort and power agree to 0.01 %."""
    got = load_train(TTO / f"{json_name}.json")
    ref = load_train(RUNS / f"{yaml_name}.yaml")
    assert got.mass_t == ref.mass_t and got.rotating_mass_factor == ref.rotating_mass_factor
    pairs = [*zip(got.davis.as_tuple(), ref.davis.as_tuple()), (got.max_tractive_effort, ref.max_tractive_effort)]
    for a, b in [*pairs, (got.max_tractive_power, ref.max_tractive_power)]:
        assert a == pytest.approx(b, rel=1e-4, abs=1e-12)


def test_assumptions_are_printed_once(capsys, tmp_path):
    path = tmp_path / "kiss.json"
    path.write_text((TTO / "CH_Stadler_KISS.json").read_text())
    load_train(path)
    load_train(path)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    for what in ("rotating mass factor 1.1 (from rho 10 %)", "length 150 m assumed (6 coaches x 25 m)",
                 "adhesive mass fraction 0.5 (assumed"):  # fmt: skip
        assert what in err[0]


def test_convert_train_writes_an_equal_yaml_with_overrides(tmp_path, capsys):
    out = tmp_path / "metro.yaml"
    code = cli.main(["convert-train", str(TTO / "CN_Beijing_Subway.json"), "--out", str(out), "--length", "118",
                     "--adhesive-mass-fraction", "0.6"])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "length 118 m (given)" in printed and "service brake 0.935 m/s^2 assumed" in printed
    text = out.read_text()
    assert "# assumption: " in text
    spec = load_train(out)
    ref = load_train(RUNS / "train_metro.yaml")
    assert spec.length_m == 118.0 and spec.adhesive_mass_fraction == 0.6
    assert spec.davis.r2 == pytest.approx(ref.davis.r2, rel=1e-5) and spec.transmission_efficiency == 0.7


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.pop("mass"), "mass: missing required key"),
        (lambda d: d["rolling resistance r1"].update(unit="kN/(m/s)"), "rolling resistance r1.unit: unit 'kN/(m/s)'"),
        (lambda d: d["rolling resistance r0"].update(value="5"), "rolling resistance r0.value: expected a number"),
        (lambda d: d["rolling resistance r0"].update(value=500.0), "davis.r0: 1.53046 N/kg is out of range"),
    ],
)
def test_bad_files_are_one_line(tmp_path, capsys, edit, message):
    data = json.loads((TTO / "CH_Stadler_KISS.json").read_text())
    edit(data)
    path = tmp_path / "t.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError) as exc:
        load_train(path)
    assert message in str(exc.value) and str(path) in str(exc.value)
    assert cli.main(["convert-train", str(path), "--out", str(tmp_path / "t.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and not (tmp_path / "t.yaml").exists()
    (tmp_path / "broken.json").write_text('{"mass": ')
    with pytest.raises(ConfigError, match="invalid JSON at line 1"):
        load_train(tmp_path / "broken.json")
