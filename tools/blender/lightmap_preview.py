"""Blender materials for a glTF written by `q3gltf convert`, after Blender's glTF import.

Blender (5.0.1) imports the lightmap as the glTF occlusion texture: an Image Texture fed by
a UV Map node on `UVMap.001` (TEXCOORD_1), wired into the "glTF Material Output" group,
which Cycles and EEVEE ignore. Vertex-lit surfaces get their COLOR_0 (baked lighting, in
the lightmap's byte encoding) multiplied into the base color by a Mix node.

- `lightmap_preview()` makes every material show what the game shows: an emission of
  `albedo x e`, with `e = byte * 2^overbright / 255` from the lightmap (or the vertex
  colours), the radiance relight fits. Render it with no lights and a black world.
- `relit_materials()` prepares the scene for rendering with real lights: vertex-lit
  materials stop multiplying their baked vertex colours into the albedo.

Usage inside Blender or with `import bpy`:

    import lightmap_preview
    lightmap_preview.lightmap_preview()          # every material of the file
"""
from __future__ import annotations

import bpy

DEFAULT_OVERBRIGHT_BITS = 2


def _principled(mat):
    return next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)


def _output(mat):
    return next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"), None)


def lightmap_image_node(mat):
    """The Image Texture node of the lightmap: its Vector input comes from a UV Map node on
    the second UV map (the importer's wiring of occlusionTexture with texCoord 1)."""
    if mat.node_tree is None:
        return None
    for n in mat.node_tree.nodes:
        if n.bl_idname != "ShaderNodeTexImage" or not n.inputs["Vector"].is_linked:
            continue
        src = n.inputs["Vector"].links[0].from_node
        if src.bl_idname == "ShaderNodeUVMap" and src.uv_map == "UVMap.001":
            return n
    return None


def lighting_kind(mat) -> str:
    """`lightmap`, `vertex` or `none`: the material extras when Blender imported them,
    else the same fallbacks as relight (a lightmap node; convert's `#vertex` name suffix)."""
    declared = mat.get("q3_lighting")
    if declared in ("lightmap", "vertex", "none"):
        return declared
    if lightmap_image_node(mat) is not None:
        return "lightmap"
    return "vertex" if "#vertex" in mat.name else "none"


def _mix_multiply(nodes, links, a, b):
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 1.0
    links.new(a, mix.inputs[6])  # A (colour)
    links.new(b, mix.inputs[7])  # B (colour)
    return mix.outputs[2]        # Result (colour)


def lightmap_preview(materials=None) -> int:
    """Rewire each material (default: all) to emit albedo x e. Returns how many changed."""
    changed = 0
    for mat in materials if materials is not None else bpy.data.materials:
        if mat.node_tree is None:
            continue
        bsdf, out = _principled(mat), _output(mat)
        if bsdf is None or out is None:
            continue
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        base = bsdf.inputs["Base Color"]
        # Albedo (the vertex-lit Mix already multiplies in COLOR_0, i.e. e / 2^overbright).
        albedo = base.links[0].from_socket if base.is_linked else None
        kind = lighting_kind(mat)
        light = None
        if kind == "lightmap":
            lm = lightmap_image_node(mat)
            lm.image.colorspace_settings.name = "Non-Color"  # bytes are linear in irradiance
            light = lm.outputs["Color"]
        emit = nodes.new("ShaderNodeEmission")
        if albedo is not None and light is not None:
            links.new(_mix_multiply(nodes, links, albedo, light), emit.inputs["Color"])
        elif albedo is not None or light is not None:
            links.new(albedo or light, emit.inputs["Color"])
        else:
            emit.inputs["Color"].default_value = base.default_value
        bits = int(mat.get("q3_overbright_bits", DEFAULT_OVERBRIGHT_BITS))
        # Unlit surfaces (light grid in the game) are shown at e = 1.
        emit.inputs["Strength"].default_value = float(2 ** bits) if kind != "none" else 1.0
        shader = emit.outputs["Emission"]
        alpha = bsdf.inputs["Alpha"]
        if alpha.is_linked:  # alpha-tested / blended: keep the cut-outs
            transparent = nodes.new("ShaderNodeBsdfTransparent")
            mix = nodes.new("ShaderNodeMixShader")
            links.new(alpha.links[0].from_socket, mix.inputs["Fac"])
            links.new(transparent.outputs["BSDF"], mix.inputs[1])
            links.new(shader, mix.inputs[2])
            shader = mix.outputs["Shader"]
        links.new(shader, out.inputs["Surface"])
        changed += 1
    return changed


def relit_materials(materials=None) -> int:
    """Vertex-lit materials: take the baked vertex colours out of the albedo (connect the
    base colour image straight to the BSDF). Returns how many changed."""
    changed = 0
    for mat in materials if materials is not None else bpy.data.materials:
        bsdf = _principled(mat) if mat.node_tree is not None else None
        if bsdf is None or lighting_kind(mat) != "vertex" or not bsdf.inputs["Base Color"].is_linked:
            continue
        src = bsdf.inputs["Base Color"].links[0].from_node
        if src.bl_idname != "ShaderNodeMix":
            continue
        image = next((l.from_socket for s in src.inputs if s.is_linked for l in s.links
                      if l.from_node.bl_idname == "ShaderNodeTexImage"), None)
        links = mat.node_tree.links
        if image is not None:
            links.new(image, bsdf.inputs["Base Color"])
        else:
            links.remove(bsdf.inputs["Base Color"].links[0])
            bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        changed += 1
    return changed
