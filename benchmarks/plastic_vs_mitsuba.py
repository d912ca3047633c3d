"""Cross-check against an independent renderer: three small scenes with the `plastic` material
(Mitsuba 3's roughplastic model) rendered here and in Mitsuba 3 (variant scalar_rgb, direct
illumination only, box pixel filter), compared by FLIP (after the same ACES + sRGB tone map) and
relative RMSE of the linear HDR. Target: FLIP <= 0.01 on each.

Mitsuba is never used at render time; this benchmark and the accuracy report's cross-check
(tissuerender/report/mitsuba.py, whose scene this script renders) need it: `.venv/bin/pip install -e '.[report]'`
first (the script says so and exits 2 when it is missing).

Usage: .venv/bin/python benchmarks/plastic_vs_mitsuba.py [--quick]
Last line: one JSON object {"<scene>": {"flip": ..., "rel_rmse": ...}, ..., "max_flip": ...}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numpy as np  # noqa: E402

from tissuerender.golden import flip  # noqa: E402
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame  # noqa: E402
# the same Mitsuba scene as the accuracy report's cross-check (scalar_rgb, direct, box filter)
from tissuerender.report.mitsuba import render_mitsuba, tonemapped as to_ldr  # noqa: E402


def plane(size=1.0, z=0.0, tilt_deg=0.0):
    h = size / 2
    pts = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    t = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    pts = pts @ rot.T + [0, 0, z]
    n = np.tile(rot @ [0.0, 0.0, 1.0], (4, 1))
    return pts, np.array([[0, 1, 2], [0, 2, 3]]), n


def sphere(centre, radius, subdivisions=5):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices) + centre, np.asarray(s.faces), np.asarray(s.vertex_normals)


SCENES = {
    "plane": dict(meshes=[plane()], cam=((0.0, -1.2, 1.0), (0.0, 0.0, 0.0)), fov=45.0,
                  light=dict(position=(0.0, 0.3, 1.2), normal=(0.0, -0.2, -1.0), size=(0.4, 0.4), radiance=6.0)),
    "sphere_on_plane": dict(meshes=[plane(1.6), sphere((0.0, 0.0, 0.25), 0.25)], cam=((0.0, -1.6, 0.9), (0.0, 0.0, 0.2)),
                            fov=45.0, light=dict(position=(0.5, 0.3, 1.3), normal=(-0.4, -0.2, -1.0), size=(0.5, 0.5),
                                                 radiance=5.0)),
    "grazing": dict(meshes=[plane(2.0, tilt_deg=10.0)], cam=((0.0, -1.5, 0.35), (0.0, 0.3, 0.0)), fov=50.0,
                    light=dict(position=(0.0, 1.2, 1.4), normal=(0.0, -0.6, -1.0), size=(0.6, 0.3), radiance=8.0)),
}


def ours(spec, width, height, samples, ss):
    objects = [RenderObject(points=p, triangles=t, normals=n, uv=None, material="plastic", object_id=i)
               for i, (p, t, n) in enumerate(spec["meshes"])]
    (pos, target), lt = spec["cam"], spec["light"]
    cam = Camera(position=pos, look_at=target, up=(0.0, 0.0, 1.0), fov_deg=spec["fov"], near=0.01, far=20.0,
                 width=width, height=height)
    light = AreaLight(size=lt["size"], radiance=(lt["radiance"],) * 3, attach="world", position=lt["position"],
                      normal=lt["normal"], sampling="uniform", samples=samples)
    out = render_frame(objects, cam, light, RenderSettings(shadows=True, supersampling=ss))
    return out.hdr.astype(np.float64), objects, cam, light


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller images and fewer samples")
    args = parser.parse_args()
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        print("mitsuba is not installed: run `.venv/bin/pip install mitsuba` (benchmark-only dependency)",
              file=sys.stderr)
        return 2
    width, height = (96, 72) if args.quick else (160, 120)
    samples, ss, spp = (64, 2, 256) if args.quick else (256, 4, 1024)
    result: dict = {"resolution": [width, height], "ours": f"{samples} light samples, {ss}x{ss} supersampling",
                    "mitsuba": f"scalar_rgb direct, {spp} spp, box filter"}
    with tempfile.TemporaryDirectory() as folder:
        for name, spec in SCENES.items():
            start = time.perf_counter()
            a, objects, cam, light = ours(spec, width, height, samples, ss)
            t_ours = time.perf_counter() - start
            start = time.perf_counter()
            b = render_mitsuba(objects, cam, light, spp, Path(folder))
            t_mi = time.perf_counter() - start
            mean_flip, _ = flip(to_ldr(b, cam), to_ldr(a, cam))
            rel = float(np.sqrt(np.mean((a - b) ** 2)) / max(np.sqrt(np.mean(b**2)), 1e-30))
            ratio = float(a.mean() / max(b.mean(), 1e-30))
            result[name] = {"flip": round(mean_flip, 5), "rel_rmse": round(rel, 5), "mean_ratio": round(ratio, 4),
                            "seconds_ours": round(t_ours, 2), "seconds_mitsuba": round(t_mi, 2)}
            print(f"{name:16s} FLIP {mean_flip:.4f}  rel RMSE {rel:.4f}  mean ours/mitsuba {ratio:.4f}  "
                  f"({t_ours:.1f} s / {t_mi:.1f} s)")
    result["max_flip"] = max(result[n]["flip"] for n in SCENES)
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus"
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
