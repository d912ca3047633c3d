"""The accuracy report's mesh-converged references for Zhang's cases (issue 17 item 1, ``zhang_mesh.py``): the
reference at several mesh levels on linear, linear + ANP and quadratic (10-node) tets, the mesh-converged line, and
each level's line errors against it, at the test suite's ("tiny") sweep: the 2-cell cube (48 tets) at levels 0-1."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sim.cases.cantilever import richardson
from sim.cases.zhang import zhang_cube_shear
from sim.mesh import procedural
from sim.mesh.refine import refine
from tissuerender.report import accuracy, claims, zhang_mesh

SWEEP = zhang_mesh.SWEEPS["tiny"]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("zhang_mesh")
    return out, accuracy.run_report(out, cases=[zhang_mesh.CASE], level="tiny")


def test_report_json_has_the_level_table_and_a_converged_line_for_each_zhang_case(report):
    out, _ = report
    study = json.loads((out / "report.json").read_text())["cases"][zhang_mesh.CASE]
    assert set(study["cases"]) == set(SWEEP["cases"])
    for name, case in study["cases"].items():
        for element, levels in (("linear", "linear_levels"), ("linear_anp", "anp_levels"),
                                ("quadratic", "quadratic_levels")):
            rows = case[element]
            assert [r["level"] for r in rows] == SWEEP[levels]
            # 1 tet -> 8 per level; a quadratic level has the nodes of the next linear level
            assert [r["tets"] for r in rows] == [rows[0]["tets"] * 8**k for k in range(len(rows))]
            for r in rows:
                assert r["line_mean_m"] <= r["line_rmse_m"] <= r["line_max_m"]  # mean <= RMS <= max
        assert case["quadratic"][0]["nodes"] == case["linear"][1]["nodes"]
        # two quadratic levels give no observed order: the converged line is the finest quadratic one, exactly
        assert case["converged"]["richardson"] is None and "finest quadratic" in case["converged"]["how"]
        assert case["quadratic"][-1]["line_max_m"] == 0.0
        assert case["converged"]["line_u_m"] == case["quadratic"][-1]["line_u_m"]
        # the shear moves the right face's middle by a sizeable part of the top's 0.5 m
        assert 0.1 < case["converged"]["mid_u_m"] < 0.5
        linear, anp, quadratic = (case[e] for e in ("linear", "linear_anp", "quadratic"))
        # at nu = 0.49 linear tets lock: on the same 125 nodes the quadratic tets are closer to the converged line
        # than the linear ones, and average nodal pressure brings the linear tets closer too
        assert quadratic[0]["line_rmse_m"] < linear[1]["line_rmse_m"]
        assert anp[1]["line_rmse_m"] < linear[1]["line_rmse_m"]
        measures = study["measures"]
        assert measures[f"{name}_linear_line_max_m"] == linear[0]["line_max_m"] > 0.0


def test_claims_against_abaqus_carry_the_mesh_error_of_the_case_mesh(report):
    _, data = report
    study = data["cases"][zhang_mesh.CASE]
    # the cube case at the mesh the study's level 0 has (48 tets): each line claim gets that level's statistic
    results = {"cube_shear": {"mesh": {"tets": 48}, "measures": {}}, zhang_mesh.CASE: study}
    rows = {row["id"]: row for row in claims.claims_table(results)}
    level0 = study["cases"]["cube_shear"]["linear"][0]
    for statistic in ("max", "mean", "rmse"):
        row = rows[f"ebm_cube_shear_{statistic}"]
        assert row["mesh_error_m"] == level0[f"line_{statistic}_m"]
        assert "the mesh's own error" in row["reason"] and "no integrator" in row["reason"]
    assert "mesh_error_m" not in rows["ebm_cube_shear_red"]  # RED is not a line error
    assert "mesh_error_m" not in rows["ebm_cylinder_extension_max"]  # the study did not run the cylinder


def test_report_html_has_a_figure_and_table_per_zhang_case(report):
    out, _ = report
    text = (out / "report.html").read_text()
    assert f'id="case-{zhang_mesh.CASE}"' in text
    for name in SWEEP["cases"]:
        assert f'data-figure="levels-{name.replace("_", "-")}"' in text and f'id="zhang-mesh-{name}"' in text
    assert text.count(f'class="{zhang_mesh.CASE}"') == len(SWEEP["cases"])
    assert "How far linear tets on the case's mesh are" in text
    assert "mesh-converged references" not in "".join(accuracy.NOT_COVERED)


def test_the_full_reports_cube_mesh_is_level_1_of_the_study():
    """refine (Bey, shortest diagonal) of the 4-cell Kuhn cube gives the 8-cell cube's tets exactly: the full
    report's cube_shear mesh is the study's level 1, so its linear row there is that case's mesh error."""
    def tets(mesh):
        return sorted(tuple(sorted(map(tuple, t))) for t in np.round(mesh.points[mesh.tets], 12))

    assert tets(refine(procedural.cube(2.0, 4))) == tets(procedural.cube(2.0, 8))


def test_quadratic_tets_converge_at_a_higher_order_and_richardson_extrapolates_beyond_the_finest_level():
    """Small strain (the cube sheared 2 mm, nu 0.3: no locking), levels 0-2 of each element on the 2-cell cube.
    Pointwise at the right face's centre, quadratic tets converge at about h^3 (observed 3.3), linear ones at about
    h (observed 0.96, the point sits on the face diagonal's midpoint, where the shear's gradient jumps); the
    extrapolated value lies beyond the finest quadratic level by less than its last change (order > 1), between
    the finest linear and quadratic levels (linear tets are too stiff, quadratic ones here too soft)."""
    base = zhang_cube_shear(n_cells=2)
    mid = int(np.argmin(np.abs(base.line_coord - 1.0)))
    rows = {element: [zhang_mesh.solve_level(zhang_cube_shear(n_cells=2, displacement=0.002, nu=0.3, level=k,
                                                               quadratic=element == "quadratic"), 1, False,
                                             base.line, k) for k in (0, 1, 2)]
            for element in ("quadratic", "linear")}
    values = {e: [r["line_u_m"][mid] for r in rows[e]] for e in rows}
    order = {e: richardson(values[e], 2.0)["observed_order"] for e in rows}
    assert order["quadratic"] > order["linear"] + 1.5
    assert 2.5 < order["quadratic"] < 4.0 and 0.7 < order["linear"] < 1.5
    conv = zhang_mesh.mesh_converged(rows, mid)
    assert conv["source"] == "quadratic" and conv["richardson"]["order_source"] == "observed"
    v1, v2 = values["quadratic"][1:]
    extrapolated = conv["line_u_m"][mid]
    assert extrapolated == pytest.approx(conv["richardson"]["extrapolated"], rel=1e-12)
    assert np.sign(extrapolated - v2) == np.sign(v2 - v1) and abs(extrapolated - v2) < abs(v2 - v1)
    assert values["linear"][-1] < extrapolated < v2
    # the converged line's error of each level falls faster for quadratic tets
    u_conv = np.asarray(conv["line_u_m"])
    errors = {e: [np.abs(np.asarray(r["line_u_m"]) - u_conv).max() for r in rows[e]] for e in rows}
    assert errors["quadratic"][0] / errors["quadratic"][1] > 2.0 * errors["linear"][0] / errors["linear"][1]
