"""Every shipped scene renders its first frame: the tissue is visible and lit, nothing is NaN."""
from __future__ import annotations

from pathlib import Path

import pytest

import tissuerender
from tissuerender.stages import StageRecorder

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_shipped_scene_renders_a_visible_lit_frame(path):
    scene = tissuerender.load_scene(path)
    recorder = StageRecorder()
    image = tissuerender.render_image(scene, resolution=(96, 72), recorder=recorder)
    assert image.shape == (72, 96, 3)
    lit = image.max(axis=2) > 25
    assert 0.03 < lit.mean() < 0.95  # an object fills part of the view, the scope's dark rim the rest
    if any(o.field_colours is not None for o in scene.objects):
        # a field colour map at rest shows its colormap's low end, dark by design (viridis: sRGB (68, 1, 84))
        assert image[lit][:, 2].mean() > 3 * image[lit][:, 1].mean()
    else:
        assert image[lit].mean() > 50
    plan = tissuerender.make_plan(scene)
    assert set(recorder.calls) <= set(plan.names)
