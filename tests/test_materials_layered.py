"""Every tissue preset is a wet layered material (issue 19 item 1): the stack returns what arrives in a white
furnace, each preset's texture has the structure it claims, and the layer keys reach the pixels from a scene
and from ``tissuerender lookdev``."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy import ndimage

import materials
from materials import patterns
from materials.optics import LAYER_KEYS, optical_value, with_overrides
from tissuerender.cli import main
from tissuerender.errors import SceneError
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame
from tissuerender.renderer.bsdf.mucosa import layered_reflectance_cos
from tissuerender.scene import load_scene

LAYERED = [n for n in materials.PRESET_NAMES if n != "plastic"]


# --- white furnace ----------------------------------------------------------------------------------------

def _ggx_directions(wo, alpha, N):
    """Reflected directions of an N x N midpoint grid of GGX half-vectors (pdf D(h) (n.h)), and their pdf."""
    u = (np.arange(N) + 0.5) / N
    u1, u2 = (a.ravel() for a in np.meshgrid(u, u, indexing="ij"))
    cos_h = np.sqrt((1 - u1) / (1 + (alpha * alpha - 1) * u1))
    sin_h = np.sqrt(1 - cos_h**2)
    h = np.stack([sin_h * np.cos(2 * np.pi * u2), sin_h * np.sin(2 * np.pi * u2), cos_h], axis=1)
    wi = 2 * (h @ wo)[:, None] * h - wo
    return wi


def _pdf_ggx(wo, wi, alpha):
    h = wo + wi
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    a2 = alpha * alpha
    D = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1) + 1) ** 2)
    return D * h[:, 2] / (4 * np.abs(h @ wo))


def _cosine_directions(N):
    u = (np.arange(N) + 0.5) / N
    u1, u2 = (a.ravel() for a in np.meshgrid(u, u, indexing="ij"))
    r = np.sqrt(u1)
    return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2), np.sqrt(1 - u1)], axis=1)


def furnace_albedo(layers, alpha, f0, theta, N=112):
    """int f(wi, wo) cos dwi over the hemisphere for albedo 1, no absorption, no SSS: a deterministic
    multi-technique quadrature (balance heuristic over a cosine grid and one GGX half-vector grid per
    distinct lobe roughness; each N x N midpoints), independent of the model's albedo tables."""
    wo = np.array([np.sin(theta), 0.0, np.cos(theta)])
    alphas = sorted({max(a, 1e-3) for a in (layers.coat_roughness, alpha, layers.granular_roughness)})
    techniques = [("cos", None)] + [("ggx", a) for a in alphas]
    total = 0.0
    for _, a in techniques:
        wi = _cosine_directions(N) if a is None else _ggx_directions(wo, a, N)
        wi = wi[wi[:, 2] > 0]
        pdf = wi[:, 2] / np.pi
        for b in alphas:
            pdf = pdf + _pdf_ggx(wo, wi, b)
        k = wi.shape[0]
        n = np.tile([0.0, 0.0, 1.0], (k, 1))
        f_cos = layered_reflectance_cos(n, np.tile(wo, (k, 1)), wi, np.ones((k, 3)), np.full(k, alpha),
                                        np.full(k, f0), None, layers.coat_roughness, layers.coat_ior,
                                        layers.coat_thickness, np.zeros((k, 3)), np.full(k, layers.granular_weight),
                                        np.full(k, layers.granular_roughness))
        total += np.sum(f_cos[:, 0] / pdf) / (N * N)
    return total


@pytest.mark.parametrize("roughness", [0.05, 0.25, 0.6])
def test_white_furnace_every_layered_preset_returns_what_arrives(roughness):
    """Albedo 1, no absorption, uniform white light: coat + everything under it returns 1 within 1 % at
    0, 45 and 75 degrees, never more (bsdf.mucosa's derivation: the diffuse share is exact, the specular
    lobes under the coat get at most what it leaves). Left over: the albedo tables' quadrature and
    interpolation (~1e-3), what min(c_i, c_o) drops of a lobe (up to 0.9 % at 75 degrees with smooth lobes),
    and this quadrature's own error (~1e-3 at N = 112, hence the 0.2 % above 1; measured 0.9904 ... 1.0012)."""
    energies = []
    for name in LAYERED:
        optics = materials.get_preset(name).optics
        layers = dataclasses.replace(optics.layers, coat_roughness=roughness, granular_roughness=roughness)
        for theta_deg in (0.0, 45.0, 75.0):
            energies.append((furnace_albedo(layers, roughness, optics.f0, np.radians(theta_deg)), name, theta_deg))
    assert 0.99 < min(energies)[0] and max(energies)[0] < 1.002, (min(energies), max(energies))


def test_furnace_fails_a_stack_that_does_not_attenuate_the_base_by_the_coat(monkeypatch):
    """The furnace check can fail: with the coat's albedo table replaced by zeros (the base no longer gives up
    what the coat reflects) the same quadrature reads 1 + E_c, about 6 % high for ior 1.8 at 45 degrees."""
    optics = materials.get_preset("liver").optics
    layers = dataclasses.replace(optics.layers, coat_roughness=0.3, coat_ior=1.8)
    good = furnace_albedo(layers, 0.3, optics.f0, np.radians(45.0))
    from tissuerender.renderer.bsdf import albedo, mucosa
    E_c, nodes = albedo.coat_table(0.3, 1.8)
    monkeypatch.setattr(mucosa, "coat_table", lambda a, ior: (np.zeros_like(E_c), np.zeros_like(nodes)))
    monkeypatch.setattr(mucosa, "coat_norms", lambda a, ior: _norms_without_coat(nodes.size))
    wrong = furnace_albedo(layers, 0.3, optics.f0, np.radians(45.0))
    assert abs(good - 1.0) < 0.01 and wrong > 1.04


def _norms_without_coat(n):
    from tissuerender.renderer.bsdf import albedo
    _, s_nodes = albedo.schlick_tables()
    _, weights = albedo.average_nodes()
    return np.stack([(1.0 - s_nodes[1]) @ weights, s_nodes[0] @ weights, (1.0 - s_nodes[0] - s_nodes[1]) @ weights])


# --- textures ---------------------------------------------------------------------------------------------

def test_vessel_tree_is_connected_branching_and_thins_by_murrays_law():
    tree = patterns.grow_tree(5, roots=1)
    n = tree.parent.size
    assert (tree.parent < np.arange(n)).all()  # every node's parent came before it: a tree, no cycles
    assert (tree.parent == -1).sum() == 1  # one root: every node reaches it
    assert tree.branch_points() > 30
    child = np.flatnonzero(tree.parent >= 0)
    assert (tree.radius[child] <= tree.radius[tree.parent[child]] * (1 + 1e-12)).all()  # thinner downstream
    means = [tree.radius[tree.generation == g].mean() for g in range(6)]
    assert all(a > b for a, b in zip(means, means[1:])), means  # and by generation
    kids = tree.children()
    for p in range(n):  # Murray: r_parent^3 = sum r_child^3 (to rounding: a few ulps of the sum)
        if kids[p]:
            assert tree.radius[p] ** 3 == pytest.approx(sum(tree.radius[c] ** 3 for c in kids[p]), rel=1e-12)
    # drawn into an image large enough to hold the unwrapped tree, its pixels form one 8-connected region
    lo, hi = tree.points.min(axis=0), tree.points.max(axis=0)
    scale = 0.9 / (hi - lo).max()
    placed = dataclasses.replace(tree, points=(tree.points - lo) * scale + 0.05, radius=np.maximum(tree.radius * scale, 0.0))
    mask = patterns.rasterise_tree(placed, 512) > 0.0
    assert ndimage.label(mask, structure=np.ones((3, 3)))[1] == 1


def test_liver_lobules_are_hexagonal_cells_of_histological_size():
    """16 x 16 cells per tile: the interiors between the septa number 256 plus the parts of cells cut by the
    tile's edges (at most 4 x 16 more); a 3 cm tile gives lobules of 30/16 = 1.9 mm (histology: 1-2 mm)."""
    f1, f2, cell = patterns.lobules(256, 16, 0.5, 21)
    assert np.unique(cell).size == 256
    interior = (f2 - f1) * 16 > 0.25
    count = ndimage.label(interior)[1]
    assert 256 <= count <= 256 + 64, count
    layers = materials.get_preset("liver").optics.layers
    assert layers.pattern == "liver_lobules"
    assert 1e-3 <= layers.texture_period / 16 <= 2e-3
    # hexagonal-ish: a cell's area is near the lattice's 1/256 of the tile (jitter spreads it)
    area = np.bincount(cell.ravel()) / cell.size * 256
    assert 0.5 < np.median(area) < 1.5 and area.min() > 0.2


def test_fat_lobules_are_larger_than_liver_lobules_and_carry_vessels_in_their_septa():
    fat = patterns.pattern("fat_lobules", 128, 29, 0.8)
    liver = patterns.pattern("liver_lobules", 128, 21, 0.6)
    n_fat = ndimage.label(fat.value > 0.6)[1]
    n_liver = ndimage.label(liver.value > 0.6)[1]
    assert n_fat < n_liver / 3
    septa = fat.value < 0.5
    assert fat.vessels[septa].mean() > 2 * fat.vessels[~septa].mean()


@pytest.mark.parametrize("name, folds", [("colon_folds", 3), ("bowel_folds", 8)])
def test_mucosa_folds_repeat_at_their_stated_count_per_tile(name, folds):
    height = patterns.pattern(name, 128, 11, 1.0).height
    spectrum = np.abs(np.fft.rfft(height.mean(axis=1) - height.mean()))
    assert int(np.argmax(spectrum[1:20])) + 1 == folds


def test_every_tissue_preset_is_layered_and_textured_with_vessels():
    for name in LAYERED:
        optics = materials.get_preset(name).optics
        assert optics.layers is not None and optics.layers.texture_seed is not None, name
        assert np.allclose(optics.layers.base_albedo, optics.albedo), name  # the stack keeps the preset's colour
        albedo = dataclasses.replace(optics.layers, texture_size=64).baked_albedo()  # small: the test's time
        assert np.allclose(albedo.reshape(-1, 3).mean(axis=0), optics.albedo, rtol=0.05, atol=0.005), name
        vessels = patterns.pattern(optics.layers.pattern, 64, optics.layers.texture_seed, optics.layers.vessel_density)
        assert 0.002 < vessels.vessels.mean() < 0.2, name
    assert {"gallbladder", "small_bowel", "vessels", "peritoneum", "fascia"} <= set(LAYERED)


# --- the layer keys reach the pixels ----------------------------------------------------------------------

def _slab(optics):
    pts = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    return RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=pts[:, :2],
                        material="liver", optics=optics)


def _render(optics):
    cam = Camera(position=(0.0, -0.02, 0.08), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=50.0,
                 near=0.01, far=1.0, width=48, height=36)
    light = AreaLight(size=(0.01, 0.01), radiance=(300.0,) * 3, samples=2)
    return render_frame([_slab(optics)], cam, light, RenderSettings()).hdr


def test_layer_overrides_move_the_shaded_values_in_the_stated_direction():
    liver = materials.get_preset("liver").optics
    base = _render(liver)
    # a sharper coat: a brighter, smaller highlight
    sharp = _render(with_overrides(liver, {"coat_roughness": 0.02}))
    assert sharp.max() > 1.5 * base.max()
    # a coat absorbing blue: less blue everywhere, red untouched to within the coat's own reflection
    blue = _render(with_overrides(liver, {"coat_absorption": [0.0, 0.0, 20000.0], "coat_thickness": 1e-4}))
    assert blue[..., 2].mean() < 0.8 * base[..., 2].mean()
    # a greener connective layer: more green diffuse light
    green = _render(with_overrides(liver, {"connective_colour": [0.5, 0.5, 0.07]}))
    assert green[..., 1].mean() > 1.5 * base[..., 1].mean()


def test_scene_optics_table_takes_layer_keys_and_refuses_them_for_plastic(tmp_path):
    head = "[scene]\nname = \"s\"\n[[objects]]\nname = \"o\"\nshape = \"slab\"\n"
    tail = "\n[camera]\nposition = [0, -0.3, 0.1]\nlook_at = [0, 0, 0]\n"
    good = tmp_path / "good.toml"
    good.write_text(head + "material = \"fat\"\n[objects.optics]\ncoat_roughness = 0.05\n"
                    "coat_absorption = [1.0, 2.0, 3.0]\ngranular_weight = 0.1\n" + tail)
    scene = load_scene(good)
    assert scene.objects[0].optics.values() == {"coat_roughness": 0.05, "coat_absorption": [1.0, 2.0, 3.0],
                                                "granular_weight": 0.1}
    bad = tmp_path / "bad.toml"
    bad.write_text(head + "material = \"plastic\"\n[objects.optics]\ncoat_roughness = 0.05\n" + tail)
    with pytest.raises(SceneError) as err:
        load_scene(bad)
    assert "objects[0].optics.coat_roughness" in str(err.value) and "no layer stack" in str(err.value)
    worse = tmp_path / "worse.toml"
    worse.write_text(head + "material = \"liver\"\n[objects.optics]\ncoat_roughness = 0.0\n" + tail)
    with pytest.raises(SceneError) as err:
        load_scene(worse)
    assert "objects[0].optics.coat_roughness" in str(err.value)


def test_lookdev_sets_and_sweeps_layer_keys(tmp_path, capsys):
    out = tmp_path / "sheet.png"
    assert main(["lookdev", "kidney", "--set", "coat_roughness=0.05", "--sweep", "granular_weight=[0.0, 0.3]",
                 "--resolution", "16x12", "--samples", "1", "-q", "-o", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert [c["overrides"] for c in report["cells"]] == [{"coat_roughness": 0.05, "granular_weight": 0.0},
                                                          {"coat_roughness": 0.05, "granular_weight": 0.3}]
    assert "coat_roughness = 0.05" in report["cells"][0]["optics_toml"]
    preset = report["preset_optics"]["kidney"]
    layers = materials.get_preset("kidney").optics.layers
    assert preset["coat_roughness"] == layers.coat_roughness and set(LAYER_KEYS) <= set(preset)
    assert main(["lookdev", "plastic", "--set", "coat_ior=1.3", "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "--set coat_ior" in err and "no layer stack" in err and err.count("\n") == 1
    assert optical_value(materials.get_preset("plastic").optics, "coat_ior") is None
