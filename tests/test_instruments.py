"""Laparoscopic instruments (issue 19 item 3): meshes, poses, steel Fresnel, silhouette, contact."""
from __future__ import annotations

import numpy as np
import pytest

from materials.optics import OPTICS
from sim.probe import Probe, resolve_contact
from tissuerender import instruments as ins
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings
from tissuerender.renderer.bsdf.microfacet import schlick_F
from tissuerender.renderer.frame import render_frame
from tissuerender.renderer.raster import project
from tissuerender.scene.schema import Tool
from tissuerender.world import make_probe

R, L = 0.0025, 0.1  # a 5 mm instrument, 10 cm of shaft in view


def _tool(kind, keyframes, axis=(0.0, 0.0, 1.0)):
    return Tool(name="t", kind=kind, radius=R, length=L, axis=list(axis), keyframes=keyframes)


def _segment_distance(p, a, b):
    return np.linalg.norm(p - ins._closest_on_segment(p, a, b), axis=1)


@pytest.mark.parametrize("kind", ins.INSTRUMENT_KINDS)
def test_capsule_meshes_are_closed_outward_and_match_the_contact_capsules(kind):
    import trimesh

    tool = _tool(kind, [{"t": 0.0, "position": [0.01, 0.02, 0.03], "orientation": [0.9, 0.3, -0.2, 0.1]}])
    caps = ins.capsules(tool, 0.0)
    assert len(caps) == 3
    pts, tris, normals = ins.instrument_surface(tool, 0.0)
    # every drawn vertex lies on a capsule's surface: distance to its nearest segment = that radius, to a few
    # ulps of the 0.1 m coordinates (rotation and translation: ~10 operations of 1.1e-16 relative)
    gap = np.min([np.abs(_segment_distance(pts, a, b) - r) for a, b, r in caps], axis=0)
    assert gap.max() < 1e-15 * 100
    for a, b, r in caps:
        v, f = ins.capsule_mesh(a, b, r)
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0.0  # outward: positive signed volume
        # the capsule's axis lies inside its (convex) drawn mesh: below every face plane by a margin
        axis = a + np.linspace(0.0, 1.0, 11)[:, None] * (b - a)
        depth = np.einsum("ijk,jk->ij", axis[:, None, :] - v[f[:, 0]][None], mesh.face_normals)
        assert depth.max() < -0.9 * r  # 16 segments: chord depth r (1 - cos(pi / 16)) ~ 0.02 r
        # the vertex normals point away from the axis
        vn = np.asarray(trimesh.Trimesh(v, f, process=False).vertex_normals)
        assert np.all(np.einsum("ij,ij->i", vn, v - ins._closest_on_segment(v, a, b)) > 0.0)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-14)


def test_pose_is_exact_at_keyframes_and_slerped_halfway():
    q1 = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # 90 deg about x
    tool = _tool("grasper", [{"t": 0.0, "position": [0.0, 0.0, 0.0], "orientation": [2.0, 0.0, 0.0, 0.0], "jaw_deg": 0.0},
                             {"t": 1.0, "position": [0.02, 0.0, -0.04], "orientation": q1, "jaw_deg": 60.0}])
    p0, R0, j0 = ins.pose(tool, 0.0)
    p1, R1, j1 = ins.pose(tool, 1.0)
    np.testing.assert_array_equal(p0, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(p1, [0.02, 0.0, -0.04])
    np.testing.assert_array_equal(R0, np.eye(3))
    np.testing.assert_array_equal(R1, ins.quat_matrix(np.asarray(q1) / np.linalg.norm(q1)))
    assert (j0, j1) == (0.0, np.radians(60.0))
    ph, Rh, jh = ins.pose(tool, 0.5)
    np.testing.assert_allclose(ph, [0.01, 0.0, -0.02], rtol=0, atol=1e-17)
    assert jh == pytest.approx(np.radians(30.0), rel=1e-15)
    # halfway: 45 deg about x, a proper rotation (unit quaternion: orthonormal to ~1e-16 per entry)
    c = np.cos(np.pi / 4)
    np.testing.assert_allclose(Rh @ [0.0, 0.0, 1.0], [0.0, -c, c], atol=4e-16)
    np.testing.assert_allclose(Rh @ Rh.T, np.eye(3), atol=4e-16)
    q = ins.slerp([1.0, 0.0, 0.0, 0.0], np.asarray(q1), 0.5)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=2e-16)
    # shortest arc: -q1 is the same rotation and gives the same halfway pose
    np.testing.assert_allclose(ins.slerp([1.0, 0.0, 0.0, 0.0], -np.asarray(q1), 0.5), q, atol=1e-16)
    # no orientation: +z turned onto the tool's axis
    plain = _tool("l_hook", [{"t": 0.0, "position": [0.0, 0.0, 0.0]}], axis=(1.0, 0.0, -1.0))
    np.testing.assert_allclose(ins.pose(plain, 0.0)[1] @ [0, 0, 1], [2 ** -0.5, 0.0, -(2 ** -0.5)], atol=2e-16)


def test_steel_fresnel_is_f0_at_normal_incidence_and_one_at_grazing():
    n, k = ins.STEEL_NK
    assert ins.STEEL_F0 == pytest.approx(((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2), rel=1e-14)
    assert 0.5 < ins.STEEL_F0 < 0.6
    assert float(ins.conductor_fresnel(0.0, n, k)) == pytest.approx(1.0, abs=1e-15)
    grazing = ins.conductor_fresnel(np.array([1.0, 0.5, 0.2, 0.05, 0.0]), n, k)
    assert grazing[-1] > grazing[-2] > grazing[0]
    # the renderer's steel: Schlick with that F0 (the preset's metal_f0 is the same formula, a few ulps)
    f0 = OPTICS["steel"].f0
    assert f0 == pytest.approx(ins.STEEL_F0, rel=1e-14)
    assert float(schlick_F(np.array([1.0]), np.array([f0]))[0]) == pytest.approx(f0, rel=1e-15)
    assert float(schlick_F(np.array([0.0]), np.array([f0]))[0]) == 1.0
    # Schlick matches the exact conductor curve near normal incidence (within 0.01 for cos >= 0.7, 46 deg) and
    # overestimates it towards grazing, where the exact curve dips (Hoffman 2019): 0.174 at cos = 0.1, 84 deg
    c = np.linspace(0.0, 1.0, 21)
    err = schlick_F(c, np.full_like(c, f0)) - ins.conductor_fresnel(c, n, k)
    assert np.abs(err[c >= 0.7]).max() < 0.01 and 0.17 < err.max() < 0.18 and err.min() >= -1e-15


def test_render_shows_the_instrument_where_its_capsules_project():
    tool = _tool("grasper", [{"t": 0.0, "position": [0.0, 0.0, 0.0], "jaw_deg": 40.0}], axis=(1.0, 0.0, 0.0))
    pts, tris, normals = ins.instrument_surface(tool, 0.0)
    cam = Camera(position=(-0.01, 0.0, 0.06), look_at=(-0.01, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=60.0,
                 near=0.005, far=1.0, width=64, height=48)
    obj = RenderObject(points=pts, triangles=tris, normals=normals, uv=None, material="steel",
                       optics=OPTICS["steel"])
    light = AreaLight(size=(0.01, 0.01), radiance=(300.0,) * 3, samples=2, offset=(0.0, 0.0, 0.0))
    frame = render_frame([obj], cam, light, RenderSettings(shadows=False, sss=False, ao=False))
    covered = np.isfinite(frame.depth)
    # pixel distance from every pixel centre to the projected capsule axes, and each capsule's projected radius
    jj, ii = np.mgrid[0:48, 0:64]
    centres = np.stack([ii + 0.5, jj + 0.5], axis=-1).reshape(-1, 2)
    inside = np.zeros(centres.shape[0], bool)
    outside = np.ones(centres.shape[0], bool)
    focal = 32.0 / np.tan(np.radians(30.0))
    for a, b, r in ins.capsules(tool, 0.0):
        axis = a + np.linspace(0.0, 1.0, 400)[:, None] * (b - a)
        sx, sy, zv = project(axis, cam, 64, 48)
        d = np.min(np.hypot(centres[:, None, 0] - sx[None], centres[:, None, 1] - sy[None]), axis=1)
        rad = r * focal / zv.max()  # the capsule's silhouette half-width is at least this (nearest depth larger)
        inside |= d < rad - 1.0  # well inside the silhouette (1 px for the axis sampling and the chords)
        outside &= d > r * focal / zv.min() + 1.0  # well outside
    inside, outside = inside.reshape(48, 64), outside.reshape(48, 64)
    assert inside.sum() > 50 and outside.sum() > 1000
    assert covered[inside].all() and not covered[outside].any()
    assert np.isfinite(frame.hdr).all() and frame.hdr[covered].max() > 0.0  # the steel catches the light


def test_grasper_pushes_tissue_like_its_capsules():
    # a node grid in the plane z = 0; a closed grasper lying flat 1 mm into it, the shaft along x
    g = np.linspace(-0.03, 0.03, 61)
    x = np.stack(np.meshgrid(g, g, [0.0], indexing="ij"), axis=-1).reshape(-1, 3)
    inv_mass = np.ones(len(x))
    tool = _tool("grasper", [{"t": 0.0, "position": [0.0, 0.0, 0.0015], "jaw_deg": 0.0}], axis=(1.0, 0.0, 0.0))
    probe = make_probe(tool)
    assert isinstance(probe, ins.InstrumentProbe)
    pushed = x.copy()
    moved = resolve_contact(pushed, probe, 0.0, inv_mass)
    # the equivalent capsules one after another, as plain probes
    ref = x.copy()
    n_ref = 0
    for a, b, r in ins.capsules(tool, 0.0):
        cap = Probe(kind="capsule", radius=r, times=[0.0], positions=[0.5 * (a + b)], axis=b - a,
                    length=float(np.linalg.norm(b - a)))
        n_ref += resolve_contact(ref, cap, 0.0, inv_mass)
    assert moved == n_ref > 50
    np.testing.assert_allclose(pushed, ref, rtol=0, atol=1e-17)  # the same projections (midpoint +- half: ulps)
    # the shaft's capsule alone is not enough: nodes under the jaws (x > 0) moved as well
    d = np.linalg.norm(pushed - x, axis=1)
    assert d[x[:, 0] > 2 * R].max() > 5e-4 and d[x[:, 0] < -2 * R].max() > 5e-4


def test_xpbd_tissue_under_a_grasper_moves_as_under_its_capsules():
    """A grasper (shaft along x, closed jaws) is pressed 3 mm into a clamped block; xpbd with the instrument's probe
    and with its three capsules as separate capsule probes gives the same nodes and the same total contact force
    (the instrument's capsules are projected in the same order, with end points equal to a few ulps)."""
    from sim.constitutive import elastic  # noqa: F401  (registers the constitutive models used by Model)
    from sim.integrators import make_integrator
    from sim.mesh import procedural, select
    from sim.model import Model, State

    r = 0.003
    tool = Tool(name="g", kind="grasper", radius=r, length=0.05, axis=[1.0, 0.0, 0.0],
                keyframes=[{"t": 0.0, "position": [0.03, 0.03, 0.025], "jaw_deg": 0.0},
                           {"t": 0.1, "position": [0.03, 0.03, 0.021], "jaw_deg": 0.0}])

    def run(probes):
        mesh = procedural.box((0.06, 0.06, 0.02), (6, 6, 2))
        model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0)
        model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
        model.probes = probes
        integrator = make_integrator("xpbd", model, {"substeps": 5, "iterations": 5, "damping": 10.0})
        state = State.at_rest(model)
        for step in range(12):
            state.t = step * 0.01
            state = integrator.step(state, 0.01)
        return mesh.points, state.x, integrator.tool_loads

    caps0, caps1 = ins.capsules(tool, 0.0), ins.capsules(tool, 0.1)
    plain = [Probe(kind="capsule", radius=r0, times=[0.0, 0.1], positions=[0.5 * (a0 + b0), 0.5 * (a1 + b1)],
                   axis=b0 - a0, length=float(np.linalg.norm(b0 - a0)))
             for (a0, b0, r0), (a1, b1, _) in zip(caps0, caps1)]
    rest, x_tool, loads_tool = run([make_probe(tool)])
    _, x_caps, loads_caps = run(plain)
    # same projections up to the end points' rounding (~1e-17 m), amplified by 60 solver sweeps: 1e-12 m
    np.testing.assert_allclose(x_tool, x_caps, rtol=0, atol=1e-12)
    total = loads_caps[:, :3].sum(axis=0)
    np.testing.assert_allclose(loads_tool[0, :3], total, rtol=0, atol=1e-9 * np.linalg.norm(total))
    assert loads_tool[0, 2] > 0.0  # the tissue pushes the tool up
    # the top nodes under the shaft went down by about the indentation (3 mm, less what they slid aside:
    # measured 1.6-1.7 mm); the thin jaws (radius 1.35 mm) pushed the node under them aside (measured 1.3 mm)
    def moved(px):
        k = int(np.argmin(np.linalg.norm(rest - [px, 0.03, 0.02], axis=1)))
        return x_tool[k] - rest[k]
    for px in (0.0, 0.01, 0.02, 0.03):
        assert -0.003 < moved(px)[2] < -0.0012
    assert np.linalg.norm(moved(0.04)) > 0.001
