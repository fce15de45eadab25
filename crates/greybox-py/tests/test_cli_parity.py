"""Python and the CLI give bit-identical results on the same data."""
from __future__ import annotations

import json

import numpy as np
import pytest

import greybox
from conftest import read_csv, sample_time


@pytest.mark.parametrize(
    "system,spec,options",
    [
        ("linear", "linear", {}),
        ("saturation", "lmn", {"order": 2, "max_leaves": 6}),
    ],
)
def test_fit_and_simulate_match_the_cli(cli, generated, tmp_path, system, spec, options):
    d = generated(system)
    cli_spec = greybox.spec_string(spec, options)
    cli("fit", d / "train.csv", "--model", cli_spec, "-o", tmp_path / "cli.gbm")
    cli("simulate", tmp_path / "cli.gbm", d / "validate.csv", "-o", tmp_path / "sim.csv")
    cli_sim = read_csv(tmp_path / "sim.csv")["y_sim"]

    tr, va = read_csv(d / "train.csv"), read_csv(d / "validate.csv")
    m = greybox.fit(tr["u"], tr["y"], spec, sample_time=sample_time(tr["t"]), **options)
    py_sim = m.simulate(va["u"])
    assert py_sim.dtype == np.float64 and py_sim.shape == va["u"].shape
    np.testing.assert_array_equal(py_sim, cli_sim)
    # the model files are the same bytes
    m.save(tmp_path / "py.gbm")
    assert (tmp_path / "py.gbm").read_bytes() == (tmp_path / "cli.gbm").read_bytes()


def test_diagnose_matches_the_cli(cli, generated, tmp_path):
    d = generated("saturation")
    cli("diagnose", d / "train.csv", "--validate", d / "validate.csv", "--json", tmp_path / "d.json")
    want = json.loads((tmp_path / "d.json").read_text())

    tr, va = read_csv(d / "train.csv"), read_csv(d / "validate.csv")
    ts = sample_time(tr["t"])
    got = greybox.diagnose(tr["u"], tr["y"], va["u"], va["y"], sample_time=ts)
    assert got.causes == [c for c in want["causes"]] == ["nonlinearity"]
    assert got.final_nrmse == want["final"]["nrmse"]
    assert got.report == want  # the whole JSON report
    assert got.to_json() == (tmp_path / "d.json").read_text()
    assert got.steps == want["steps"] and len(got.steps) > 0
    assert "adequate" in got.verdict or got.verdict == want["verdict"]["text"]
    # the final model simulates the validation data as the report says
    m = got.final_model
    assert m.class_name == want["final"]["class"]
    assert m.describe() == want["final"]["model"]


def test_diagnose_without_validation_splits_like_the_cli(cli, generated, tmp_path):
    d = generated("linear")
    cli("diagnose", d / "train.csv", "--json", tmp_path / "d.json", "--max-steps", "1",
        "--save", tmp_path / "cli.gbm")
    want = json.loads((tmp_path / "d.json").read_text())
    tr = read_csv(d / "train.csv")
    got = greybox.diagnose(tr["u"], tr["y"], max_steps=1, sample_time=sample_time(tr["t"]))
    assert got.report == want
    assert got.causes == []
    # the model kept is the one refitted on all of the training data, as
    # the CLI saves it (the decisions line says so)
    assert "the model saved: the chosen structure refitted on all" in want["data"]["decision"]
    got.final_model.save(tmp_path / "py.gbm")
    assert (tmp_path / "py.gbm").read_bytes() == (tmp_path / "cli.gbm").read_bytes()


def test_diagnose_of_several_experiments_matches_the_cli(cli, generated, tmp_path):
    d = generated("saturation")
    tr = read_csv(d / "train.csv")
    header = (d / "train.csv").read_text().splitlines()
    (tmp_path / "a.csv").write_text("\n".join(header[:1] + header[1:1501]) + "\n")
    (tmp_path / "b.csv").write_text("\n".join(header[:1] + header[1501:]) + "\n")
    cli("diagnose", "--train", tmp_path / "a.csv", "--train", tmp_path / "b.csv",
        "--json", tmp_path / "d.json", "--save", tmp_path / "cli.gbm")
    want = json.loads((tmp_path / "d.json").read_text())
    ts = sample_time(tr["t"])
    got = greybox.diagnose(tr["u"][:1500], tr["y"][:1500], sample_time=ts,
                           experiments=[(tr["u"][1500:], tr["y"][1500:])])
    assert got.causes == want["causes"]
    assert got.final_nrmse == want["final"]["nrmse"]
    assert got.steps == want["steps"]
    assert got.report["data"]["decision"] == want["data"]["decision"]
    # the second record held out whole for the report, then the model kept
    # refitted on both records
    assert [r["report"] for r in got.report["data"]["records"]] == [0, 1500]
    assert "refitted on all 2 training records whole" in want["data"]["decision"]
    got.final_model.save(tmp_path / "py.gbm")
    assert (tmp_path / "py.gbm").read_bytes() == (tmp_path / "cli.gbm").read_bytes()
    with pytest.raises(ValueError, match="experiment 2 has 2 inputs"):
        greybox.diagnose(tr["u"], tr["y"], experiments=[(np.c_[tr["u"], tr["u"]], tr["y"])])


def test_html_report(generated, tmp_path):
    d = generated("saturation")
    tr, va = read_csv(d / "train.csv"), read_csv(d / "validate.csv")
    got = greybox.diagnose(tr["u"], tr["y"], va["u"], va["y"], max_steps=1)
    got.report_html(tmp_path / "r.html", title="saturation")
    html = (tmp_path / "r.html").read_text()
    assert html.startswith("<!DOCTYPE html>") or "<html" in html[:200]
    assert "saturation" in html
