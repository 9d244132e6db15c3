"""The Blender loop: import the relit oa_dm1, edit it as a user would (move a light, delete
one, lock one, delete geometry, add a cube), export with Blender's default options plus
'Punctual Lights' (and once more with 'Custom Properties'), then `q3gltf relight --init
input` on the export."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from helpers import RELIGHT_FAST, VARIANTS, light_nodes, read_gltf_json, run, triangle_count, validate


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_blender_export_after_edit(edited, dm1_relit, variant):
    before = read_gltf_json(dm1_relit)
    after = read_gltf_json(edited["paths"][variant])
    # Blender declares the lights extension required: our reader has to accept that.
    assert "KHR_lights_punctual" in after.get("extensionsRequired", [])

    l0, l1 = light_nodes(before), light_nodes(after)
    assert sorted(l1) == sorted(set(l0) - {edited["deleted"]})
    for name, (node, light) in l1.items():
        node0, light0 = l0[name]
        want = edited["moved_to"] if name == edited["moved"] else node0["translation"]
        assert np.allclose(node["translation"], want, atol=1e-5), name
        assert math.isclose(light["intensity"], light0["intensity"], rel_tol=1e-5), name
        assert np.allclose(light["color"], light0.get("color", [1, 1, 1]), atol=1e-6), name

    assert triangle_count(after) == triangle_count(before) - edited["removed_triangles"] + 12
    cube = next(n for n in after["nodes"] if n.get("name") == edited["cube"])
    for prim in after["meshes"][cube["mesh"]]["primitives"]:
        assert "TEXCOORD_1" not in prim["attributes"]
        assert "occlusionTexture" not in after["materials"][prim["material"]] if "material" in prim else True
    lightmapped = [m for m in after["materials"] if m.get("occlusionTexture", {}).get("texCoord") == 1]
    assert len(lightmapped) > 10

    extras = {n["name"]: n.get("extras") for n in after["nodes"]}
    if variant == "lights":
        assert not any(extras.values())  # Blender drops extras unless asked
    else:
        assert extras[edited["locked"]] == {"locked": True}
        assert sum(1 for e in extras.values() if e and e.get("classname") == "info_player_deathmatch") > 1


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_relight_blender_export(edited, q3gltf, node_validator, dm1_relit, workdir, variant):
    src = edited["paths"][variant]
    out = workdir / f"edited.{variant}.relit.glb"
    report_path = workdir / f"edited.{variant}.report.json"
    run(q3gltf, "relight", src, "-o", out, "--init", "input", "--report", report_path, *RELIGHT_FAST)
    report = json.loads(report_path.read_text())
    exported = read_gltf_json(src)

    assert validate(node_validator, out)["errors"] == 0
    # It read the whole edited file: every triangle, the cube included.
    assert report["triangles_input"] == triangle_count(exported)
    # Not worse than the edited start.
    print(f"\n{variant}: rel_error {report['rel_error_initial']:.4f} -> {report['rel_error_final']:.4f}")
    assert report["rel_error_final"] <= report["rel_error_initial"] + 1e-9
    # And close to where the first relight ended before the edits (0.65 vs 0.67 measured).
    first = json.loads((workdir / "oa_dm1.report.json").read_text())["rel_error_final"]
    assert report["rel_error_final"] <= first + 0.05, (first, report["rel_error_final"])

    locked = [l for l in report["lights"] if l["locked"]]
    if variant == "lights":
        assert locked == []  # the flag travels only in extras ('Custom Properties')
        return
    # relight renames the lights it writes (light_000, ...): find the locked one by its flag.
    assert len(locked) == 1, locked
    assert np.allclose(locked[0]["position_m"], edited["locked_at"], atol=1e-5)
    assert math.isclose(locked[0]["intensity_cd"], edited["locked_cd"], rel_tol=1e-5)
    written = [(n, l) for n, l in light_nodes(read_gltf_json(out)).values() if (n.get("extras") or {}).get("locked")]
    assert len(written) == 1
    node, light = written[0]
    assert np.allclose(node["translation"], edited["locked_at"], atol=1e-5)
    assert math.isclose(light["intensity"], edited["locked_cd"], rel_tol=1e-5)
