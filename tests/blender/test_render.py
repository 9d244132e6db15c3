"""`make render`'s script (tools/blender/render.py) at a tiny size: the relit oa_dm1 with its
point lights and the lightmapped original (lightmap_preview.py's emission materials), from
the same spawn point. The lightmapped image must show the room, the relit one its point lights' light."""
from __future__ import annotations

import numpy as np

import render


def _pixels(bpy, path):
    img = bpy.data.images.load(str(path))
    w, h = img.size
    px = np.array(img.pixels[:]).reshape(h, w, 4)[:, :, :3]
    bpy.data.images.remove(img)
    return px


def test_render_pair(bpy, dm1, dm1_relit, workdir):
    out = workdir / "render"
    relit, lightmap = render.render_pair(dm1_relit, dm1, out, width=64, height=36, samples=8,
                                         denoise=False, small_width=32)
    lit = {}
    for path in (relit, lightmap):
        px = _pixels(bpy, path)
        assert px.shape == (36, 64, 3), path
        assert (out / "small" / path.name).is_file()
        # Pixels that show something: neither black nor blown out.
        lit[path.name] = float(((px.max(axis=2) > 0.02) & (px.min(axis=2) < 0.98)).mean())
    print(f"\nfraction of lit pixels: {lit}")
    # The lightmapped room fills the picture (the camera stands inside it, emission works).
    assert lit["lightmap.png"] > 0.8
    # The relit one is lit by its point lights: how well depends on the fit (this test's is
    # a 3x3 grid start with 10 iterations), not on the script.
    assert lit["relit.png"] > 0.05
