"""The bake after the Blender loop: the edited export (a cube added in Blender, which has no
lightmap coordinates) baked with `q3gltf bake`. The cube is charted into a new atlas
(xatlas) and lit by the file's lights; baked.glb passes the validator, its charts never
share a filtered texel, Blender imports it with the atlas wired like convert's lightmaps
(an image node on the second UV map), and relight reads it with the cube as data."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from helpers import RELIGHT_FAST, VARIANTS, import_gltf, run, validate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
from gltf_io import charts_sharing_filtered_texels, read_glb  # noqa: E402


@pytest.fixture(scope="module")
def bakes(edited, q3gltf, workdir) -> dict[str, tuple[Path, dict]]:
    out = {}
    for variant, src in edited["paths"].items():
        d = workdir / f"bake.{variant}"
        run(q3gltf, "bake", src, "-o", d, "--backend", "cpu", "--bounces", "0", "-q")
        out[variant] = (d / "baked.glb", json.loads((d / "bake.json").read_text()))
    return out


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_bake_charts_the_added_cube(bakes, edited, node_validator, variant):
    glb, report = bakes[variant]
    atlas = report["atlas"]
    # Only the cube lacked lightmap coordinates (convert's unlit materials keep their
    # "#unlit" name without extras, and are left alone).
    assert atlas is not None and atlas["primitives"] == 1 and atlas["triangles"] == 12, atlas
    assert validate(node_validator, glb)["errors"] == 0
    doc, binary = read_glb(glb)
    img = next(i for i, im in enumerate(doc["images"]) if im.get("name") == "lightmap_atlas")
    cube = next(n for n in doc["nodes"] if n.get("name") == edited["cube"])
    for prim in doc["meshes"][cube["mesh"]]["primitives"]:
        assert "TEXCOORD_1" in prim["attributes"]
        occ = doc["materials"][prim["material"]]["occlusionTexture"]
        assert occ["texCoord"] == 1 and doc["textures"][occ["index"]]["source"] == img
    shared, charts = charts_sharing_filtered_texels(doc, binary, img)
    assert charts >= 1 and shared == 0, (shared, charts)
    page = next(p for p in report["pages"] if p["new"])
    # 0.4 m faces at the map's 0.21 m texels: one to four texel centres each (measured 8 in
    # all), lit by the map's lights.
    assert page["texels"] >= 6 and max(page["relit_mean"]) > 0.0, page
    # The map's own lightmap (convert packs its pages into one image) is still there,
    # relit, with its residual.
    own = [p for p in report["pages"] if not p["new"]]
    assert own and all(p["residual_rms"] is not None and p["texels"] > 10000 for p in own), own


def test_blender_wires_the_new_atlas_like_converts_lightmaps(bpy, bakes, edited, q3gltf, node_validator, workdir):
    glb, report = bakes["lights"]
    import_gltf(bpy, glb)
    cube = bpy.data.objects[edited["cube"]]
    assert [uv.name for uv in cube.data.uv_layers] == ["UVMap", "UVMap.001"]
    mat = cube.material_slots[0].material
    lm = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"
          and n.image is not None and n.image.name == "lightmap_atlas"]
    assert len(lm) == 1, [n.bl_idname for n in mat.node_tree.nodes]
    uv = [l.from_node for l in lm[0].inputs["Vector"].links]
    assert [n.bl_idname for n in uv] == ["ShaderNodeUVMap"] and uv[0].uv_map == "UVMap.001"
    assert lm[0].outputs["Color"].is_linked
    assert tuple(lm[0].image.size) == (report["atlas"]["width"], report["atlas"]["height"])

    # And back out: Blender's export keeps the cube's atlas in the same slot, and the bake
    # of that export finds nothing left to chart.
    back = workdir / "baked.roundtrip.glb"
    bpy.ops.export_scene.gltf(filepath=str(back), export_lights=True)
    assert validate(node_validator, back)["errors"] == 0
    doc, _ = read_glb(back)
    node = next(n for n in doc["nodes"] if n.get("name") == edited["cube"])
    for prim in doc["meshes"][node["mesh"]]["primitives"]:
        occ = doc["materials"][prim["material"]]["occlusionTexture"]
        assert "TEXCOORD_1" in prim["attributes"] and occ["texCoord"] == 1
        assert doc["images"][doc["textures"][occ["index"]]["source"]]["name"] == "lightmap_atlas"
    again = workdir / "bake.roundtrip"
    run(q3gltf, "bake", back, "-o", again, "--backend", "cpu", "--bounces", "0", "-q")
    r = json.loads((again / "bake.json").read_text())
    assert r["atlas"] is None and r["luxels"] == report["luxels"], (r["atlas"], r["luxels"], report["luxels"])


def test_relight_reads_the_baked_file_with_the_cube_as_data(bakes, q3gltf, workdir):
    glb, report = bakes["lights+extras"]
    rep = workdir / "baked.relight.json"
    run(q3gltf, "relight", glb, "-o", workdir / "baked.relit.glb", "--init", "input", "--report", rep, *RELIGHT_FAST)
    r = json.loads(rep.read_text())
    # Every texel the bake wrote is a luxel row now, the cube's included.
    assert r["luxel"]["luxels"] + r["luxel"]["buried"] >= report["luxels"] * 0.99
    assert not any("without TEXCOORD_1" in s for s in r["skipped_primitives"]), r["skipped_primitives"]
