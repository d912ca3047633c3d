"""The accuracy report's discretisation section (issue 17 item 1): the cantilever on linear and quadratic tets at
the test suite's ("tiny") sweep: a (3, 1, 1)-cell beam at levels 0 and 1 under 1/1000 gravity."""
from __future__ import annotations

import json

import numpy as np
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


SMALL_SCENE = """
[scene]
name = "small_block"

[[objects]]
name = "block"
shape = "box"
size = [0.1, 0.1, 0.1]
cell_size = 0.05
material = "liver"
override = { E = 1e4 }
fixed = [{ side = "z_min" }]
prescribed = [{ side = "z_max", displacement = [0.02, 0.0, -0.02], t_start = 0.0, t_end = 0.125 }]

[simulation]
integrator = "xpbd"
dt = 0.020833333333333332
substeps = 2
iterations = 4
gravity = [0.0, 0.0, 0.0]

[camera]
position = [0.0, -0.3, 0.15]
look_at = [0.0, 0.0, 0.0]

[light]
attach = "camera"
size = [0.05, 0.05]
radiance = [3000.0, 3000.0, 3000.0]

[output]
resolution = [64, 48]
frames = 2
fps = 24.0
"""


def test_scene_reference_on_the_refined_mesh_holds_the_regions_and_differs_from_the_scene_mesh(tmp_path):
    """The scene's report measures the mesh's own error: the reference on the 1:8-refined block (384 tets) against
    the one on the scene's 48 tets, at the same step, over one frame interval of the ramp."""
    from tissuerender import load_scene
    from tissuerender.report.scene import reference_trajectory, refined_reference_trajectory, relative_errors

    path = tmp_path / "small.toml"
    path.write_text(SMALL_SCENE)
    scene = load_scene(path)
    step = scene.simulation.dt / 2
    fine, _, tets = refined_reference_trajectory(scene, 2, step)
    coarse, _ = reference_trajectory(scene, 2, step)
    assert tets == 8 * 48 and fine[0].shape == coarse[0].shape == (27, 3)  # the scene's nodes only
    rest = coarse[0]
    bottom, top = rest[:, 2] == rest[:, 2].min(), rest[:, 2] == rest[:, 2].max()
    assert (fine[1][bottom] == rest[bottom]).all()  # the fixed region, held on the refined mesh
    ramp = (1.0 / 24.0) / 0.125  # the prescribed face's share of its displacement at frame 2
    assert fine[1][top] - rest[top] == pytest.approx(np.tile([0.02 * ramp, 0.0, -0.02 * ramp], (top.sum(), 1)))
    # one cell through the block's height is coarse: the two meshes' answers differ by per cents, not by nothing
    # and not by the whole motion
    error = relative_errors(coarse, fine, rest)[1]
    assert 1e-3 < error < 0.5
