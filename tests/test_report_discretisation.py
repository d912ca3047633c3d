"""The accuracy report's discretisation section (issue 17 item 1): the cantilever on linear and quadratic tets at
the test suite's ("tiny") sweep: a (3, 1, 1)-cell beam at levels 0 and 1 under 1/1000 gravity."""
from __future__ import annotations

import json

import pytest

from sim.cases.cantilever import beam_theory_tip_deflection
from tissuerender.report import accuracy, discretisation


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("discretisation")
    return out, accuracy.run_report(out, cases=[discretisation.CASE], level="tiny")


def test_report_states_a_mesh_converged_tip_and_the_linear_tets_error_per_level(report):
    out, data = report
    case = data["cases"][discretisation.CASE]
    assert json.loads((out / "report.json").read_text())["cases"][discretisation.CASE]["converged_tip_m"] == \
        pytest.approx(case["converged_tip_m"])
    theory = beam_theory_tip_deflection(discretisation.SWEEPS["tiny"]["gravity_scale"])
    # two quadratic levels, assumed order 3: the extrapolation lands within 3 % of beam theory (the clamped face and
    # 3D effects make the rest), the linear tets' errors are large and fall with the level, the quadratic's small
    assert case["richardson"]["order_source"] == "assumed"
    assert abs(case["converged_tip_m"] / theory - 1.0) <= 0.03
    errors = [r["relative_error"] for r in case["linear"]]
    assert errors[0] > errors[1] > 0.3  # locked: a (6, 2, 2)-cell beam of linear tets is far off
    assert case["quadratic"][-1]["relative_error"] < 0.02
    reach = case["to_reach_1pct"]
    assert reach["how"] == "extrapolated" and reach["level"] > 1 and reach["tets"] > case["linear"][-1]["tets"]
    assert case["issue_claim"]["verdict"] == "not comparable"  # level 3 is the full report's
    lock = case["locking"]
    # at nu 0.49 ANP frees the linear tets' volumetric locking: more deflection than without
    assert lock["linear_anp"]["tip_deflection"] > lock["linear"]["tip_deflection"]


def test_report_html_has_the_discretisation_figure_and_tables(report):
    out, _ = report
    text = (out / "report.html").read_text()
    assert f'id="case-{discretisation.CASE}"' in text
    assert 'data-figure="discretisation"' in text
    assert text.count('class="discretisation"') == 2
    assert "Mesh-converged tip deflection" in text and "What it takes to reach 1 %" in text
