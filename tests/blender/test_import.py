"""Blender (bpy 5.0.1) imports what q3gltf writes, with Blender's default import options:
the converted oa_dm1 (meshes, both UV maps, base colour images, the lightmap on the second
UV map, vertex colours of vertex-lit surfaces, entity empties with their keys) and the
relit oa_dm1 (one point light per glTF light, right place, watts and colour)."""
from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from helpers import accessor, gltf_to_blender, import_gltf, light_nodes, read_gltf_json, triangle_count


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", head[16:24])


def _linked_from(socket):
    return [l.from_node for l in socket.links]


def test_import_converted_map(bpy, dm1):
    doc = read_gltf_json(dm1)
    import_gltf(bpy, dm1)
    objs = bpy.data.objects

    # Meshes: one object per glTF mesh node, every triangle there, both UV maps.
    mesh_nodes = [n for n in doc["nodes"] if "mesh" in n]
    meshes = {o.name: o for o in objs if o.type == "MESH"}
    assert sorted(meshes) == sorted(n["name"] for n in mesh_nodes)
    assert sum(len(o.data.polygons) for o in meshes.values()) == triangle_count(doc)
    for o in meshes.values():
        assert [uv.name for uv in o.data.uv_layers] == ["UVMap", "UVMap.001"], o.name

    # The second UV map holds TEXCOORD_1 (v flipped by the importer): compare extremes and
    # means over the world mesh.
    world_node = next(n for n in mesh_nodes if n["name"] == "world")
    tc1 = np.concatenate([accessor(doc, dm1, p["attributes"]["TEXCOORD_1"])
                          for p in doc["meshes"][world_node["mesh"]]["primitives"]
                          if "TEXCOORD_1" in p["attributes"]])
    world = meshes["world"].data
    uv1 = np.empty(2 * len(world.loops))
    world.uv_layers["UVMap.001"].data.foreach_get("uv", uv1)
    uv1 = uv1.reshape(-1, 2)
    uv1[:, 1] = 1.0 - uv1[:, 1]
    # Primitives without TEXCOORD_1 (vertex-lit) get zeros in Blender's shared UV map.
    has_tc1 = [s.material.node_tree.nodes.get("UV Map") is not None for s in meshes["world"].material_slots]
    loop_mask = np.zeros(len(world.loops), bool)
    for poly in world.polygons:
        if has_tc1[poly.material_index]:
            loop_mask[list(poly.loop_indices)] = True
    uv1 = uv1[loop_mask]
    assert np.allclose(uv1.min(axis=0), tc1.min(axis=0), atol=1e-6)
    assert np.allclose(uv1.max(axis=0), tc1.max(axis=0), atol=1e-6)

    # Materials: base colour image into the BSDF, lightmap through a UV Map node on UVMap.001.
    images = doc["images"]
    textures = doc["textures"]
    n_lightmapped = 0
    for m in doc["materials"]:
        mat = bpy.data.materials[m["name"]]
        nodes = mat.node_tree.nodes
        bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        # Lambertian as the model assumes: KHR_materials_specular 0 reaches the BSDF.
        assert m["extensions"]["KHR_materials_specular"]["specularFactor"] == 0.0
        assert bsdf.inputs["Specular IOR Level"].default_value == 0.0, (m["name"], bsdf.inputs["Specular IOR Level"].default_value)
        base_tex = m.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if base_tex is not None:
            gl_image = images[textures[base_tex["index"]]["source"]]
            # Directly, or through the importer's Mix with the vertex colours.
            feeders = _linked_from(bsdf.inputs["Base Color"])
            assert feeders, m["name"]
            if feeders[0].bl_idname == "ShaderNodeMix":
                feeders = [l.from_node for s in feeders[0].inputs if s.is_linked for l in s.links]
            tex = [n for n in feeders if n.bl_idname == "ShaderNodeTexImage"]
            assert len(tex) == 1, (m["name"], [n.bl_idname for n in feeders])
            assert tex[0].image.name == gl_image["name"]
            assert tuple(tex[0].image.size) == _png_size(dm1.parent / gl_image["uri"]) \
                if gl_image["uri"].endswith(".png") else tex[0].image.size[0] > 0
        occ = m.get("occlusionTexture")
        if occ is not None:
            assert occ["texCoord"] == 1
            gl_image = images[textures[occ["index"]]["source"]]
            lm = [n for n in nodes if n.bl_idname == "ShaderNodeTexImage"
                  and n.image is not None and n.image.name == gl_image["name"]]
            assert len(lm) == 1, m["name"]
            uv = _linked_from(lm[0].inputs["Vector"])
            assert [n.bl_idname for n in uv] == ["ShaderNodeUVMap"], m["name"]
            assert uv[0].uv_map == "UVMap.001"
            assert lm[0].outputs["Color"].is_linked  # into the glTF Material Output's Occlusion
            assert tuple(lm[0].image.size) == _png_size(dm1.parent / gl_image["uri"])
            n_lightmapped += 1
    assert n_lightmapped > 10

    # Vertex colours on vertex-lit surfaces: the glTF COLOR_0 at each position.
    exp_pos, exp_col = [], []
    vertex_lit = set()
    for prim in doc["meshes"][world_node["mesh"]]["primitives"]:
        m = doc["materials"][prim["material"]]
        if m.get("extras", {}).get("q3_lighting") != "vertex":
            continue
        vertex_lit.add(m["name"])
        pos = accessor(doc, dm1, prim["attributes"]["POSITION"])
        col = accessor(doc, dm1, prim["attributes"]["COLOR_0"])[:, :3]
        exp_pos.append(np.stack([pos[:, 0], -pos[:, 2], pos[:, 1]], axis=1))  # Blender axes
        exp_col.append(col)
    exp_pos, exp_col = np.concatenate(exp_pos), np.concatenate(exp_col)
    assert vertex_lit
    attr = world.color_attributes[0]
    assert attr.domain == "CORNER"
    slot_names = [s.material.name for s in meshes["world"].material_slots]
    checked, worst, spread = 0, 0.0, 0.0
    for poly in world.polygons:
        if slot_names[poly.material_index] not in vertex_lit:
            continue
        for li in poly.loop_indices:
            co = np.array(world.vertices[world.loops[li].vertex_index].co)
            near = np.abs(exp_pos - co).max(axis=1) < 1e-4
            assert near.any(), f"no vertex-lit glTF vertex at {co}"
            got = np.array(attr.data[li].color[:3])
            worst = max(worst, np.abs(exp_col[near] - got).max(axis=1).min())
            spread = max(spread, np.abs(got - 1.0).max())
            checked += 1
    assert checked > 100
    assert worst < 0.01, f"vertex colour differs from COLOR_0 by {worst}"
    assert spread > 0.2  # real lighting, not a white default

    # Entity empties: name, keys as custom properties, position.
    entity_nodes = [n for n in doc["nodes"] if "classname" in n.get("extras", {}) and "mesh" not in n]
    assert len(entity_nodes) > 20
    for n in entity_nodes:
        o = objs[n["name"]]
        assert o.type == "EMPTY"
        props = {k: o[k] for k in o.keys()}
        assert props == n["extras"], n["name"]
        assert np.allclose(o.matrix_world.translation, gltf_to_blender(n.get("translation", [0, 0, 0])), atol=1e-5)
    assert sum(1 for n in entity_nodes if n["extras"]["classname"] == "info_player_deathmatch") > 1


def test_import_relit_lights(bpy, dm1_relit):
    doc = read_gltf_json(dm1_relit)
    lights = light_nodes(doc)
    assert len(lights) > 3
    import_gltf(bpy, dm1_relit)
    blights = {o.name: o for o in bpy.data.objects if o.type == "LIGHT"}
    assert sorted(blights) == sorted(lights)
    for name, (node, light) in lights.items():
        o = blights[name]
        assert o.data.type == "POINT"
        assert np.allclose(o.matrix_world.translation, gltf_to_blender(node["translation"]), atol=1e-5), name
        watts = light["intensity"] * 4 * math.pi / 683
        assert math.isclose(o.data.energy, watts, rel_tol=1e-5), (name, o.data.energy, watts)
        assert np.allclose(o.data.color, light.get("color", [1, 1, 1]), atol=1e-6), name
