"""`q3gltf bake`'s glTF output (baked.glb) checked from outside: the Khronos validator on a
real map baked in its own layout and charted anew (`--new-uvs`, xatlas), the new atlas
wired in convert's slot (occlusionTexture on TEXCOORD_1, clamped, linear), and a point
light over a plane charted anew and baked, texel by texel against the analytic irradiance
at the point of the plane each texel of the new atlas stands for (found from the file's own
TEXCOORD_1, read here with numpy).
"""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from gltf_io import accessor, image_bytes, png_size, read_glb
from test_bake_exr import CANDELA, HEIGHT_M, OFFSET_M, plane_scene, read_rgba


def bake(q3gltf: Path, src: Path, out: Path, *extra: str) -> dict:
    subprocess.run([str(q3gltf), "bake", str(src), "-o", str(out), "--backend", "cpu", "--bounces", "0", "-q", *extra],
                   check=True, capture_output=True, timeout=600)
    return json.loads((out / "bake.json").read_text())


@pytest.fixture(scope="module")
def dm1_bakes(q3gltf, baseoa, tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    d: Path = tmp_path_factory.mktemp("bake_gltf")
    src = d / "oa_dm1.gltf"
    subprocess.run([str(q3gltf), "convert", "oa_dm1", "--game-dir", str(baseoa), "-q", "-o", str(src)],
                   check=True, capture_output=True, timeout=300)
    return {name: (d / name / "baked.glb", bake(q3gltf, src, d / name, *extra))
            for name, extra in [("layout", ()), ("atlas", ("--new-uvs",))]}


@pytest.mark.parametrize("variant", ["layout", "atlas"])
def test_baked_glb_passes_the_khronos_validator(dm1_bakes, node_validator, variant) -> None:
    glb, _ = dm1_bakes[variant]
    res = subprocess.run(["node", str(node_validator), str(glb)], capture_output=True, text=True, check=True)
    report = json.loads(res.stdout.strip().splitlines()[-1])
    assert report["errors"] == 0 and report["warnings"] == 0, report


def test_new_atlas_is_wired_in_converts_slot(dm1_bakes) -> None:
    glb, report = dm1_bakes["atlas"]
    doc, binary = read_glb(glb)
    atlas = report["atlas"]
    img = next(i for i, im in enumerate(doc["images"]) if im.get("name") == "lightmap_atlas")
    assert png_size(image_bytes(doc, binary, img)) == (atlas["width"], atlas["height"])
    lightmapped = [m for m in doc["materials"] if m.get("occlusionTexture", {}).get("texCoord") == 1]
    assert len(lightmapped) == len(atlas["materials"]) > 5
    for m in lightmapped:
        tex = doc["textures"][m["occlusionTexture"]["index"]]
        assert tex["source"] == img, m["name"]
        s = doc["samplers"][tex["sampler"]]
        assert (s["wrapS"], s["wrapT"], s["magFilter"], s["minFilter"]) == (33071, 33071, 9729, 9729)
    charted = 0
    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            m = doc["materials"][p["material"]] if "material" in p else {}
            if m.get("occlusionTexture", {}).get("texCoord") != 1:
                continue
            uv = accessor(doc, binary, p["attributes"]["TEXCOORD_1"])
            assert uv.min() >= 0.0 and uv.max() <= 1.0
            pos = accessor(doc, binary, p["attributes"]["POSITION"])
            assert len(pos) == len(uv)
            charted += len(accessor(doc, binary, p["indices"])) // 3
    assert charted == atlas["triangles"]


def test_plane_charted_anew_matches_the_analytic_irradiance(q3gltf: Path, tmp_path: Path) -> None:
    src = plane_scene(tmp_path)
    out = tmp_path / "bake"
    report = bake(q3gltf, src, out, "--new-uvs", "--texel-size", "0.1")
    assert report["atlas"]["charts"] >= 1 and report["pages"][0]["new"]
    relit = read_rgba(out / "lightmap_atlas.relit.exr")
    h, w = relit.shape[:2]
    doc, binary = read_glb(out / "baked.glb")
    p = doc["meshes"][0]["primitives"][0]
    pos = accessor(doc, binary, p["attributes"]["POSITION"]).astype(np.float64)
    uv = accessor(doc, binary, p["attributes"]["TEXCOORD_1"]).astype(np.float64) * [w, h]
    tris = accessor(doc, binary, p["indices"]).reshape(-1, 3)
    checked, worst = 0, 0.0
    lx, ly, lz = 0.3, HEIGHT_M, -0.2
    for y, x in zip(*np.nonzero(relit[..., 3] == 1.0)):
        c = np.array([x + 0.5, y + 0.5])
        for t in tris:
            a, b, d = uv[t]
            m = np.array([b - a, d - a]).T
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            s, r = np.linalg.solve(m, c - a)
            if s >= -1e-4 and r >= -1e-4 and s + r <= 1 + 1e-4:
                wp = pos[t[0]] + s * (pos[t[1]] - pos[t[0]]) + r * (pos[t[2]] - pos[t[0]])
                dist = np.sqrt((lx - wp[0]) ** 2 + (ly - OFFSET_M) ** 2 + (lz - wp[2]) ** 2)
                e = CANDELA / 683.0 * (ly - OFFSET_M) / dist ** 3 / np.pi
                worst = max(worst, float(np.abs(relit[y, x, :3] - e).max() / e))
                checked += 1
                break
        else:
            pytest.fail(f"texel ({x}, {y}) is covered but no triangle of the file holds its centre")
    # 4 m x 4 m at 0.1 m per texel: about 1600 texels.
    assert 1400 < checked < 1800, checked
    assert worst < 2e-5, f"largest relative difference {worst:.2e}"
