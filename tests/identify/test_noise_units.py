"""A declared tracker noise in the wrong unit: ``--noise`` takes units, and residuals far below the declared noise
make model_fit warn of a unit slip instead of passing with every uncertainty 1000x too large."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from identify.commands.cli import main
from identify.estimator.adequacy import assess
from identify.results import verdict

SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"
SAMPLE_NOISE = 5e-5  # m per axis: the noise the sample was made with (sample_ur5e_truth.yaml)
SIGMA = 1e-5  # m per axis, the white noise of the synthetic fit below


def _white_noise_fit(declared: float):
    """The assessment of 1440 rows of white noise SIGMA about their fitted mean, against ``declared`` (m)."""
    rng = np.random.default_rng(5)
    data = rng.normal(0.0, SIGMA, (1440, 3))
    jac = np.broadcast_to(np.eye(3), (len(data), 3, 3)).copy()
    runs = [np.arange(s * 36, (s + 1) * 36) for s in range(40)]
    return assess(data - data.mean(axis=0), jac, np.full(len(data), -1), runs, 1.0, declared)


@pytest.mark.parametrize(("declared", "status"), [(SIGMA, "pass"), (3 * SIGMA, "pass"), (1e3 * SIGMA, "warn"),
                                                  (25.4 * SIGMA, "warn")])
def test_residuals_far_below_the_declared_noise_warn_of_a_unit_slip(declared, status):
    """A spec 3x pessimistic is a spec; 25.4x (inches) and 1000x (mm read as m) are unit slips."""
    check = verdict.model_fit(SIGMA, _white_noise_fit(declared))
    assert check.status == status, check.message
    assert ("unit slip" in check.message) == (status == "warn")


def _identify(noise: str, capsys) -> dict:
    assert main([str(SAMPLE), "--noise", noise, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_noise_in_millimetres_is_read_as_such_and_a_bare_millimetre_value_warns(capsys):
    right = _identify("0.05mm", capsys)
    fit = {c["name"]: c for c in right["verdict"]["checks"]}["model_fit"]
    assert fit["status"] == "pass"
    assert right["noise"]["declared_per_axis"] == pytest.approx(SAMPLE_NOISE, rel=1e-12)
    slip = {c["name"]: c for c in _identify("0.05", capsys)["verdict"]["checks"]}["model_fit"]
    assert slip["status"] == "warn" and "unit slip" in slip["message"]
    assert "(--noise 0.05 is read as 50 mm; did you mean 0.05mm?)" in slip["message"]
    assert slip["value"] == pytest.approx(SAMPLE_NOISE, rel=0.2)  # the residual noise: the sample's own


def test_a_noise_without_a_known_unit_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as info:
        main([str(SAMPLE), "--noise", "0.05 mmm"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--noise" in err and "0.05mm" in err


def test_the_verdict_repeats_what_was_typed_when_the_noise_is_a_unit_slip(capsys):
    """The model_fit check says what was typed and what was probably meant (issue 39, items 2 and 14c)."""
    fit = {c["name"]: c for c in _identify("50mm", capsys)["verdict"]["checks"]}["model_fit"]
    assert "(--noise 50mm is read as 50 mm; did you mean 50um?)" in fit["message"]
    fit = {c["name"]: c for c in _identify("50um", capsys)["verdict"]["checks"]}["model_fit"]
    assert fit["status"] == "pass" and "did you mean" not in fit["message"]


def test_a_sigma_column_in_millimetres_is_named_as_the_slip():
    check = verdict.model_fit(SIGMA, _white_noise_fit(1e3 * SIGMA), noise_column=True)
    assert check.status == "warn" and "the sigma column, median 10 mm, is in the positions' unit" in check.message
