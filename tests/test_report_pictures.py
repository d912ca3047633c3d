"""The accuracy report's new parts (issue 17 items 1 and 3, issue 21 item 5): the error-field picture shows the colour
map's range on the mesh, force against indentation agrees with the reference and rises with depth, the claims table
has a row and a verdict for every claim the issue lists, and the Mitsuba section says when it did not run."""
from __future__ import annotations

import numpy as np
import pytest

from sim.mesh import procedural
from sim.model import Model
from tissuerender.report import claims, indentation, mitsuba
from tissuerender.report.pictures import COLORMAP, error_field_image, error_fields


def _colour_indices(image: np.ndarray) -> np.ndarray:
    """The colour map's index (0-255) of every pixel within 12 (sum over RGB) of one of its 256 colours; white
    background, black edges and the anti-aliased pixels between them match none."""
    import matplotlib

    lut = np.round(matplotlib.colormaps[COLORMAP](np.linspace(0.0, 1.0, 256))[:, :3] * 255.0)
    colours, counts = np.unique(image.reshape(-1, 3), axis=0, return_counts=True)
    distance = np.abs(colours[:, None, :].astype(np.float64) - lut[None, :, :]).sum(axis=2)
    nearest = distance.argmin(axis=1)
    close = distance[np.arange(len(colours)), nearest] <= 12.0
    return np.repeat(nearest[close], counts[close])  # one entry per pixel


def test_error_field_picture_shows_the_colour_maps_whole_range_on_the_mesh():
    mesh = procedural.box((0.1, 0.1, 0.1), (3, 3, 3))
    model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0)
    X = model.X
    # error |u - u_ref| grows with z + y: 0 along the bottom front edge, largest along the top back edge; the
    # isometric view from (+1, +1, +1) sees the top, +x and +y faces, which run from the middle of the range to its top,
    # and the +x face, which runs from 0 up
    u_ref = np.zeros_like(X)
    small = np.zeros_like(X)
    small[:, 0] = 1e-3 * (X[:, 1] + X[:, 2])
    large = 10.0 * small
    points = [{"integrator": "xpbd", "setting": "1x1", "rel_l2": 0.5, "_u": large},
              {"integrator": "xpbd", "setting": "5x20", "rel_l2": 0.05, "_u": small},
              {"integrator": "ebm", "setting": "20 it", "diverged": "non-finite positions"}]
    fields = error_fields(model, points, u_ref)
    assert [p["which"] for p in fields["panels"]] == ["best", "worst"]
    assert [p["setting"] for p in fields["panels"]] == ["xpbd 5x20", "xpbd 1x1"]
    assert all("_u" not in p for p in points)  # the full displacements are not stored per point
    image = error_field_image(fields, scalar_bars=False, labels=False)
    half = image.shape[1] // 2
    for panel in (image[:, :half], image[:, half:]):
        coloured = _colour_indices(panel)
        assert coloured.size > 0.05 * panel.shape[0] * panel.shape[1]  # the mesh covers the panel, not blank
        # each panel has its own range [0, its largest error]: both ends of the colour map appear (a constant or
        # clipped colouring, or the worst's range on the best, would not)
        assert coloured.min() <= 8 and coloured.max() >= 247


def test_force_against_indentation_agrees_with_the_reference_and_rises_with_depth():
    case = indentation.run_indentation(indentation.SWEEPS["tiny"])
    rows = case["rows"]
    assert [r["depth_mm"] for r in rows] == [2.5, 5.0, 10.0]
    # XPBD's contact impulses against the Newton reaction at the touched nodes (measured -0.46 %, -1.05 %, -0.49 %)
    assert abs(rows[0]["relative_difference"]) < 0.02
    assert all(abs(r["relative_difference"]) < 0.02 for r in rows)
    force = [r["xpbd_fz_N"] for r in rows]
    assert 0.0 < force[0] < force[1] < force[2]
    # contact stiffening: the contact area grows with depth, so doubling 5 -> 10 mm more than doubles the force
    # (Hertz on a half-space: 2^1.5 = 2.83; measured 2.74 on the 10 cm block)
    assert 2.2 < force[2] / force[1] < 3.2
    assert case["measures"]["force_rises_with_depth"] is True


# every quantitative claim issue 17 names ("The theses' claims, side by side") and the case that measures it
ISSUE_CLAIMS = {
    "ebm_cylinder_extension_max", "ebm_cylinder_extension_mean", "ebm_cylinder_extension_rmse",
    "ebm_cylinder_compression_max", "ebm_cylinder_compression_mean", "ebm_cylinder_compression_rmse",
    "ebm_cube_shear_max", "ebm_cube_shear_mean", "ebm_cube_shear_rmse",
    "ebm_cylinder_compression_red", "ebm_cylinder_extension_red", "ebm_cube_shear_red",  # Zhang §5.3
    "cnn_msd_small_step", "cnn_msd_large_step_stable", "cnn_msd_K2_worse_small_step",
    "cnn_msd_smaller_K_better_large_step", "cnn_msd_K4_better_K5_large_step",  # Zhang §4.3.2.1
    "cnn_cube_small_step", "cnn_cube_large_step_explicit_diverges", "cnn_cube_large_step_cnn_stable",  # §4.3.2.2
    "ebm_rate_isotropic", "ebm_rate_anisotropic", "cnn_energy_rate",  # the rates
    "qian_xpbd_100_iterations", "qian_newton_7_iterations", "qian_xpbd_above_newton",  # Qian §4.4.3
    "painted_sampling_cost",  # Qian §6.3.2
    "qian_frame_time_breakdown",  # Qian ch. 7
}


def test_claims_table_lists_every_claim_of_the_issue_with_a_verdict():
    # the measures as the cases store them (liver: measured 0.050 and 8.6e-14; cube: the docs' figures)
    results = {"liver_variational": {"measures": {"xpbd_100_variational_error": 0.050,
                                                  "newton_7_variational_error": 8.6e-14}},
               "cnn_cube": {"measures": {"small_step_difference_m": 1e-13, "small_step_sag_m": 0.012,
                                         "explicit_large_step_diverged": True, "cnn_large_step_peak_m": 0.19,
                                         "cube_size_m": 1.0}}}
    table = {row["id"]: row for row in claims.claims_table(results)}
    assert ISSUE_CLAIMS <= set(table)
    assert all(row["verdict"] in ("reproduced", "not reproduced", "not comparable") and row["reason"]
               for row in table.values())
    assert table["qian_xpbd_100_iterations"]["verdict"] == "not reproduced"  # 500x the thesis's 1e-4
    assert table["qian_newton_7_iterations"]["verdict"] == "reproduced"
    assert table["qian_xpbd_above_newton"]["verdict"] == "reproduced"
    assert table["cnn_cube_small_step"]["verdict"] == "reproduced"
    assert table["cnn_cube_large_step_explicit_diverges"]["verdict"] == "reproduced"
    assert table["cnn_cube_large_step_cnn_stable"]["verdict"] == "reproduced"
    assert table["qian_frame_time_breakdown"]["verdict"] == "not comparable"
    assert "case msd not run" in table["cnn_msd_small_step"]["reason"]
    flipped = {"cnn_cube": {"measures": {**results["cnn_cube"]["measures"], "explicit_large_step_diverged": False}}}
    assert claims.verdict(next(c for c in claims.CLAIMS if c.id == "cnn_cube_large_step_explicit_diverges"),
                          flipped)["verdict"] == "not reproduced"


def test_mitsuba_section_says_not_run_when_mitsuba_is_missing(monkeypatch):
    monkeypatch.setattr(mitsuba, "available", lambda: "mitsuba not installed (pip install mitsuba)")
    case = mitsuba.run_mitsuba(mitsuba.SWEEPS["tiny"])
    assert case["skipped"].startswith("not run: mitsuba not installed")
    from tissuerender.report.html import mitsuba_section

    assert "not run: mitsuba not installed" in mitsuba_section({**case, "cached": False})


def test_ours_agrees_with_mitsuba_on_the_rough_plastic_kidney():
    pytest.importorskip("mitsuba")
    scene = mitsuba.run_scene("kidney_static", mitsuba.SWEEPS["tiny"])
    assert [p["samples"] for p in scene["points"]] == [1, 16]
    # the same material model, light and camera: mean brightness within 2 % (measured 0.999 at 48 x 36) and FLIP
    # below benchmarks/plastic_vs_mitsuba.py's target of 0.01 (measured 0.0045; at 32 x 24 the edges alias: 0.012)
    assert all(abs(p["brightness_ratio"] - 1.0) < 0.02 for p in scene["points"])
    assert all(p["flip"] < 0.01 for p in scene["points"])


def test_the_rate_case_keeps_its_cnn_block_beside_zhangs_cnn_cube_case():
    # the report's CNN cube module once shadowed sim.cases.rates.cnn_cube in cases.py, and the full report's CNN
    # energy rate (not run by --quick or the tests' sweeps) failed with "'module' object is not callable"
    from sim.cases import rates
    from tissuerender.report import cases

    assert cases.cnn_cube is rates.cnn_cube
    assert cases.EXTRA["cnn_cube"][1].__module__ == "tissuerender.report.cnn_cube"
