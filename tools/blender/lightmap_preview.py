"""Blender materials for a glTF written by `q3gltf convert`, after Blender's glTF import.

Blender (5.0.1) imports the lightmap as the glTF occlusion texture: an Image Texture fed by
a UV Map node on `UVMap.001` (TEXCOORD_1), wired into the "glTF Material Output" group,
which Cycles and EEVEE ignore. Vertex-lit surfaces get their COLOR_0 (baked lighting, in
the lightmap's byte encoding) multiplied into the base color by a Mix node.

- `lightmap_preview()` makes every material show what the game shows: an emission of
  `albedo x e`, with `e = byte * 2^overbright / 255` from the lightmap (or the vertex
  colours), the radiance relight fits. Render it with no lights and a black world.
- `game_preview()` makes every material show what the game's screen shows: the engine
  (ioquake3's classic renderer) multiplies 8-bit display values, the texture's sRGB bytes
  times the lightmap shifted by the overbright bits and clamped keeping its hue, and the
  screen turns that into light: an emission of `srgb_decode(T_srgb * L)` with
  `L = e / max(1, max channel of e)` (the sRGB transfer function, about `x^2.2`, the
  same curve tools/game/compare.py decodes the frames with). The floor of what any linear renderer can be
  compared with the game's frame (texture filtering, items, the sky are the rest).
- `relit_materials()` prepares the scene for rendering with real lights: vertex-lit
  materials stop multiplying their baked vertex colours into the albedo, and relight's
  ambient term (scene extras `q3_relight.ambient`, W/m^2) becomes each lit material's
  emission `albedo x E_a / pi`: the light q3map2 adds everywhere, which no lamp and no
  world colour can reach inside a closed map; and what casts no shadow in q3map2 (the
  sky, glass and other shaders that say so) casts none in Cycles, and the camera sees
  the sky's texture, not the sky light it emits, and a surface light's texture, not the
  radiance relight fitted for it; light bounced off a surface carries the fit's bounce
  scale (the albedo every ray but the camera's sees).

Usage inside Blender or with `import bpy`:

    import lightmap_preview
    lightmap_preview.lightmap_preview()          # every material of the file
"""
from __future__ import annotations

import bpy

import node_math

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


def _rewirable(materials=None):
    """(material, Principled BSDF, output node, nodes, links) of each material (default:
    all) that has both nodes, as the importer wires them."""
    for mat in materials if materials is not None else bpy.data.materials:
        if mat.node_tree is None:
            continue
        bsdf, out = _principled(mat), _output(mat)
        if bsdf is not None and out is not None:
            yield mat, bsdf, out, mat.node_tree.nodes, mat.node_tree.links


def lightmap_preview(materials=None) -> int:
    """Rewire each material (default: all) to emit albedo x e. Returns how many changed."""
    changed = 0
    for mat, bsdf, out, nodes, links in _rewirable(materials):
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
        links.new(_keep_cutouts(nodes, links, bsdf, emit.outputs["Emission"]), out.inputs["Surface"])
        changed += 1
    return changed


def srgb_decode(nodes, links, colour):
    """Nodes for the sRGB transfer function's inverse per channel of a colour socket
    (display value -> light; node_math.srgb_decode per channel)."""
    sep = nodes.new("ShaderNodeSeparateColor")
    links.new(colour, sep.inputs["Color"])
    comb = nodes.new("ShaderNodeCombineColor")
    for i in range(3):
        links.new(node_math.srgb_decode(nodes, links, sep.outputs[i]), comb.inputs[i])
    return comb.outputs["Color"]


def _keep_cutouts(nodes, links, bsdf, shader):
    """Alpha-tested or blended materials keep their cut-outs: `shader` mixed with a
    Transparent BSDF by the BSDF's alpha input, when it is linked."""
    alpha = bsdf.inputs["Alpha"]
    if not alpha.is_linked:
        return shader
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(alpha.links[0].from_socket, mix.inputs["Fac"])
    links.new(transparent.outputs["BSDF"], mix.inputs[1])
    links.new(shader, mix.inputs[2])
    return mix.outputs["Shader"]


def _image_and_light(mat, kind):
    """The base colour image's output (or None) and the baked light's output (lightmap
    image or colour attribute; None for unlit), from convert's wiring after import."""
    bsdf = _principled(mat)
    base = bsdf.inputs["Base Color"]
    image, light = _base_image(bsdf), None
    if kind == "vertex" and base.is_linked and base.links[0].from_node.bl_idname == "ShaderNodeMix":
        light = next((l.from_socket for sock in base.links[0].from_node.inputs for l in sock.links
                      if l.from_node.bl_idname in ("ShaderNodeVertexColor", "ShaderNodeAttribute")), None)
    if kind == "lightmap":
        lm = lightmap_image_node(mat)
        lm.image.colorspace_settings.name = "Non-Color"
        light = lm.outputs["Color"]
    return image, light


def game_preview(materials=None) -> int:
    """Rewire each material (default: all) to emit what the game's screen shows (see the
    module docs). Textures are read as their raw sRGB bytes. Returns how many changed."""
    changed = 0
    for mat, bsdf, out, nodes, links in _rewirable(materials):
        kind = lighting_kind(mat)
        image, light = _image_and_light(mat, kind)
        factor = bsdf.inputs["Base Color"].default_value
        display = None  # T_srgb * factor
        if image is not None:
            image.image.colorspace_settings.name = "Non-Color"
            display = image.outputs["Color"]
        if light is not None:
            bits = int(mat.get("q3_overbright_bits", DEFAULT_OVERBRIGHT_BITS))
            shifted = nodes.new("ShaderNodeVectorMath")
            shifted.operation = "SCALE"
            links.new(light, shifted.inputs[0])
            shifted.inputs["Scale"].default_value = float(2 ** bits)
            sep = nodes.new("ShaderNodeSeparateColor")
            links.new(shifted.outputs["Vector"], sep.inputs["Color"])
            peak = nodes.new("ShaderNodeMath")
            peak.operation = "MAXIMUM"
            links.new(sep.outputs[0], peak.inputs[0])
            links.new(sep.outputs[1], peak.inputs[1])
            peak2 = nodes.new("ShaderNodeMath")
            peak2.operation = "MAXIMUM"
            links.new(peak.outputs[0], peak2.inputs[0])
            links.new(sep.outputs[2], peak2.inputs[1])
            floor1 = nodes.new("ShaderNodeMath")
            floor1.operation = "MAXIMUM"
            links.new(peak2.outputs[0], floor1.inputs[0])
            floor1.inputs[1].default_value = 1.0
            inv = nodes.new("ShaderNodeMath")
            inv.operation = "DIVIDE"
            inv.inputs[0].default_value = 1.0
            links.new(floor1.outputs[0], inv.inputs[1])
            clamped = nodes.new("ShaderNodeVectorMath")  # L = e / max(1, max channel)
            clamped.operation = "SCALE"
            links.new(shifted.outputs["Vector"], clamped.inputs[0])
            links.new(inv.outputs[0], clamped.inputs["Scale"])
            lit = clamped.outputs["Vector"]
            display = _mix_multiply(nodes, links, display, lit) if display is not None else lit
        emit = nodes.new("ShaderNodeEmission")
        if display is not None:
            tint = nodes.new("ShaderNodeMix")  # the material's factor (1 for convert's maps)
            tint.data_type = "RGBA"
            tint.blend_type = "MULTIPLY"
            tint.inputs["Factor"].default_value = 1.0
            links.new(display, tint.inputs[6])
            tint.inputs[7].default_value = factor if image is not None else (1.0, 1.0, 1.0, 1.0)
            links.new(srgb_decode(nodes, links, tint.outputs[2]), emit.inputs["Color"])
        else:
            emit.inputs["Color"].default_value = factor
        emit.inputs["Strength"].default_value = 1.0
        links.new(_keep_cutouts(nodes, links, bsdf, emit.outputs["Emission"]), out.inputs["Surface"])
        changed += 1
    return changed


def _relit_rgb(key: str, keep):
    """A per-channel value of relight's scene extras (`q3_relight.KEY`, imported as the
    scene's custom property), or None when absent or when `keep(values)` is false."""
    relit = bpy.context.scene.get("q3_relight")
    value = relit.get(key) if relit is not None else None
    if value is None:
        return None
    value = [float(v) for v in value]
    return value if len(value) == 3 and keep(value) else None


def scene_ambient_irradiance():
    """relight's ambient irradiance (W/m^2 per channel), or None."""
    return _relit_rgb("ambient", lambda v: any(x > 0 for x in v))


def add_ambient(ambient_w_m2, materials=None) -> int:
    """Each lit, non-emissive material also emits `albedo x E_a / pi` (radiance of a
    Lambertian surface under irradiance E_a): relight's ambient term, which every lit
    surface receives and none passes on. The emission is seen by camera rays only (as a
    light it lit its neighbours too: a floor between two white walls read 1.75 times its
    ambient radiance). Returns how many changed."""
    import math
    colour = [v / math.pi for v in ambient_w_m2]
    changed = 0
    for mat in materials if materials is not None else bpy.data.materials:
        bsdf = _principled(mat) if mat.node_tree is not None else None
        if bsdf is None or lighting_kind(mat) == "none":
            continue
        if mat.get("q3_ambient_emission"):
            continue  # done before
        if bsdf.inputs["Emission Strength"].default_value > 0 and (
                bsdf.inputs["Emission Color"].is_linked or any(bsdf.inputs["Emission Color"].default_value[:3])):
            continue  # a surface light: its emission is its own
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        base = bsdf.inputs["Base Color"]
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.blend_type = "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
        if base.is_linked:
            links.new(base.links[0].from_socket, mix.inputs[6])
        else:
            mix.inputs[6].default_value = base.default_value
        mix.inputs[7].default_value = (*colour, 1.0)
        links.new(mix.outputs[2], bsdf.inputs["Emission Color"])
        bsdf.inputs["Emission Strength"].default_value = 1.0
        # What the camera sees of the ambient, not a light: no other ray sees the emission,
        # and no light sampling picks it (which would evaluate it with the flags of the
        # point it lights: a camera-lit point would see it).
        links.new(nodes.new("ShaderNodeLightPath").outputs["Is Camera Ray"], bsdf.inputs["Emission Strength"])
        mat.cycles.emission_sampling = "NONE"
        mat["q3_ambient_emission"] = True  # not a surface light (surface_light_materials)
        changed += 1
    return changed


def is_sky_object(obj) -> bool:
    """Under convert's "sky" node (Blender adds ".001" to a clashing name)."""
    while obj is not None:
        if obj.name == "sky" or (obj.name.startswith("sky.") and obj.name[4:].isdigit()):
            return True
        obj = obj.parent
    return False


def shadows_as_q3map2() -> int:
    """Surfaces that cast no shadow in q3map2 cast none in Cycles either: the sky (a sun or
    sky ray that reaches a sky surface has reached the sky; a material is sky wherever it
    is used once it is used under convert's "sky" node, as relight reads it) and materials
    whose shader says so (extras `q3_casts_shadow` false: glass, some sky and effect
    shaders). As plain geometry a glass roof or the sky brushes would put the map in the
    sun's shadow. relight leaves these surfaces out of every ray it traces (shadow rays
    and bounces alike), so in Cycles each such material lets every ray but the camera's
    through (Light Path "Is Camera Ray"); one that emits (the sky, a surface light) becomes
    its emission plus a Transparent BSDF, which lights and blocks nothing else, for every
    ray (the camera sees it through the copies of `sky_as_seen` and `emitters_as_seen`;
    a camera flag would leak into its direct light: Cycles evaluates a mesh light with
    the shading point's flags). ("Is Shadow Ray" is not enough: Cycles does not raise it
    for the shadow rays of a mesh light's direct light, and oacmpdm4's platform got 0.17 of
    its sky light behind a star shell.) Returns how many materials changed."""
    sky = sky_materials()
    mats = sky | {m for m in bpy.data.materials if m.get("q3_casts_shadow") is False or m.get("q3_casts_shadow") == 0}
    emitting = sky | surface_light_materials()
    changed = 0
    for mat in mats:
        if mat.get("q3_shadow_rule_applied"):
            continue
        out = _output(mat) if mat.node_tree is not None else None
        if out is None or not out.inputs["Surface"].is_linked:
            continue
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        clear = nodes.new("ShaderNodeBsdfTransparent")
        bsdf = _principled(mat)
        if mat in emitting and bsdf is not None:
            emit = nodes.new("ShaderNodeEmission")
            colour = bsdf.inputs["Emission Color"]
            if colour.is_linked:
                links.new(colour.links[0].from_socket, emit.inputs["Color"])
            else:
                emit.inputs["Color"].default_value = colour.default_value
            emit.inputs["Strength"].default_value = bsdf.inputs["Emission Strength"].default_value
            add = nodes.new("ShaderNodeAddShader")
            links.new(clear.outputs["BSDF"], add.inputs[0])
            links.new(emit.outputs["Emission"], add.inputs[1])
            links.new(add.outputs["Shader"], out.inputs["Surface"])
        else:
            shader = out.inputs["Surface"].links[0].from_socket
            path = nodes.new("ShaderNodeLightPath")
            mix = nodes.new("ShaderNodeMixShader")
            links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
            links.new(clear.outputs["BSDF"], mix.inputs[1])
            links.new(shader, mix.inputs[2])
            links.new(mix.outputs["Shader"], out.inputs["Surface"])
        mat["q3_shadow_rule_applied"] = True
        changed += 1
    return changed


def sky_materials() -> set:
    """Materials used under convert's "sky" node (sky wherever they are used, as relight
    reads them)."""
    return {slot.material for o in bpy.data.objects if o.type == "MESH" and is_sky_object(o) and not o.get("q3_sky_copy")
            for slot in o.material_slots if slot.material is not None}


def _base_image(bsdf):
    """The image texture node behind a Principled BSDF's base colour: linked directly, or
    through one Mix node (the importer multiplies an unlit or vertex-lit material's image
    by its vertex colours: COLOR_0). None where there is none."""
    base = bsdf.inputs["Base Color"]
    if not base.is_linked:
        return None
    src = base.links[0].from_node
    if src.bl_idname == "ShaderNodeTexImage":
        return src
    if src.bl_idname in ("ShaderNodeMix", "ShaderNodeMixRGB"):
        return next((l.from_node for i in src.inputs if i.is_linked for l in i.links
                     if l.from_node.bl_idname == "ShaderNodeTexImage"), None)
    return None


def _as_seen_material(mat, name: str, additive: bool = False):
    """A material that shows the camera `mat`'s base colour (its image, through the same UV
    map, or its flat colour) as emission at strength 1, the way the game draws a surface at
    full brightness, and lights nothing. With `additive`, the emission is added over what
    lies behind (a Transparent BSDF plus the emission): the game's additive blend, which
    shows an effect texture's black as no change (flames)."""
    m = bpy.data.materials.new(name)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    out = nodes.new("ShaderNodeOutputMaterial")
    shader = emit.outputs["Emission"]
    if additive:
        add = nodes.new("ShaderNodeAddShader")
        links.new(nodes.new("ShaderNodeBsdfTransparent").outputs["BSDF"], add.inputs[0])
        links.new(shader, add.inputs[1])
        shader = add.outputs["Shader"]
        m.surface_render_method = "BLENDED"
    links.new(shader, out.inputs["Surface"])
    bsdf = _principled(mat) if mat is not None and mat.node_tree is not None else None
    src = _base_image(bsdf) if bsdf is not None else None
    if src is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = src.image
        uv = src.inputs["Vector"].links[0].from_node if src.inputs["Vector"].is_linked else None
        if uv is not None and uv.bl_idname == "ShaderNodeUVMap":
            uvn = nodes.new("ShaderNodeUVMap")
            uvn.uv_map = uv.uv_map
            links.new(uvn.outputs["UV"], tex.inputs["Vector"])
        links.new(tex.outputs["Color"], emit.inputs["Color"])
    elif bsdf is not None and not bsdf.inputs["Base Color"].is_linked:
        emit.inputs["Color"].default_value = bsdf.inputs["Base Color"].default_value
    else:
        # A base colour from something other than an image: black rather than the
        # socket's unused default (white).
        emit.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    m.cycles.emission_sampling = "NONE"  # lights nothing
    return m


def _camera_copy(o, look, flag: str):
    """A copy of `o` sharing its mesh, seen only by the camera, each material slot showing
    `look(material)`; `o` itself is hidden from camera rays and lights and shadows as
    before. (A parented copy keeps the parent.) Returns the copy."""
    copy = o.copy()
    copy[flag] = True
    for coll in o.users_collection:
        coll.objects.link(copy)
    for slot_o, slot_c in zip(o.material_slots, copy.material_slots):
        slot_c.link = "OBJECT"
        slot_c.material = look(slot_o.material)
    copy.visible_diffuse = copy.visible_glossy = copy.visible_transmission = False
    copy.visible_volume_scatter = copy.visible_shadow = False
    o.visible_camera = False
    return copy


def sky_as_seen() -> int:
    """The camera sees the sky's texture (as the game draws it, at full brightness), not
    the sky light relight wrote as its emission, which still lights the scene: each object
    under convert's "sky" node is hidden from camera rays, and a copy sharing its mesh,
    seen only by the camera, shows each material's base colour as emission that lights
    nothing. (A Light Path "Is Camera Ray" mix would leak into direct light: Cycles
    evaluates a mesh light with the shading point's camera flag.) Returns how many objects
    got a copy."""
    looks = {}

    def look_of(mat):
        if mat not in looks:
            looks[mat] = _as_seen_material(mat, (mat.name if mat else "sky") + " (as seen)")
        return looks[mat]

    changed = 0
    for o in [o for o in bpy.data.objects if o.type == "MESH" and is_sky_object(o) and not o.get("q3_sky_look")]:
        copy = _camera_copy(o, look_of, "q3_sky_copy")
        copy["q3_sky_look"] = True
        o["q3_sky_look"] = True
        changed += 1
    return changed


def surface_light_materials() -> set:
    """Materials the file makes emit (relight's surface lights: the importer sets the
    Principled BSDF's emission from `emissiveFactor` and `KHR_materials_emissive_strength`),
    other than the sky's. Read it before `add_ambient` gives lit materials an emission."""
    sky = sky_materials()
    found = set()
    for mat, bsdf, _out, _nodes, _links in _rewirable():
        colour = bsdf.inputs["Emission Color"]
        if mat in sky or mat.get("q3_ambient_emission") or bsdf.inputs["Emission Strength"].default_value <= 0:
            continue
        if colour.is_linked or any(c > 0 for c in colour.default_value[:3]):
            found.add(mat)
    return found


def _split_off_faces(o, slots: set):
    """Moves the faces of `o` whose material slot index is in `slots` into a new object
    (same transform, parent and collections, its own mesh with the same materials) and
    returns it; `o` keeps the rest. None where no face is in `slots`; `o` itself where
    every face is (nothing to split)."""
    import bmesh
    mats = [f.material_index for f in o.data.polygons]
    inside = sum(1 for i in mats if i in slots)
    if inside == 0:
        return None
    if inside == len(mats):
        return o
    if o.data.users > 1:
        o.data = o.data.copy()
    part = o.copy()
    part.data = o.data.copy()
    for coll in o.users_collection:
        coll.objects.link(part)
    for mesh, keep_inside in ((part.data, True), (o.data, False)):
        bm = bmesh.new()
        bm.from_mesh(mesh)
        gone = [f for f in bm.faces if (f.material_index in slots) != keep_inside]
        bmesh.ops.delete(bm, geom=gone, context="FACES")
        bm.to_mesh(mesh)
        bm.free()
        mesh.update()
    return part


def emitters_as_seen(emitters=None) -> int:
    """The camera sees a surface light's texture, as the game draws it (at full brightness;
    added over what lies behind where the material blends, as the game's additive effect
    shaders do), not the radiance relight fitted for it (tens of times the texture
    on a flame), which still lights the scene. The faces of each surface-light material
    (default: `surface_light_materials()`) move into an object of their own, hidden from
    camera rays, and a camera-only copy shows the look, as `sky_as_seen` does for the sky.
    Returns how many objects got a copy."""
    emitters = surface_light_materials() if emitters is None else set(emitters)
    if not emitters:
        return 0
    looks = {}

    def look_of(mat):
        if mat not in emitters:
            return mat
        if mat not in looks:
            additive = getattr(mat, "surface_render_method", "") == "BLENDED"
            looks[mat] = _as_seen_material(mat, mat.name + " (as seen)", additive)
        return looks[mat]

    changed = 0
    for o in [o for o in bpy.data.objects if o.type == "MESH" and not is_sky_object(o) and not o.get("q3_emitter_look")]:
        slots = {i for i, s in enumerate(o.material_slots) if s.material in emitters}
        part = _split_off_faces(o, slots) if slots else None
        if part is None:
            continue
        part["q3_emitter_look"] = True
        copy = _camera_copy(part, look_of, "q3_emitter_copy")
        copy["q3_emitter_look"] = True
        changed += 1
    return changed


def scene_bounce_scale():
    """relight's fitted scale of each bounce pass (per channel), or None when the fit has
    no bounce term."""
    return _relit_rgb("bounce_scale", lambda v: all(x > 0 for x in v))


def scale_bounces(scale, materials=None) -> int:
    """Light bounced off a lit material carries relight's bounce scale: the model's pass
    `T_{k+1} = s K rho T_k` is what Cycles computes when every ray but the camera's sees the
    albedo `s rho` (Light Path "Is Camera Ray": the camera, and the Diffuse Color pass, still
    see `rho`). Returns how many materials changed."""
    changed = 0
    sky = sky_materials()
    for mat, bsdf, out, nodes, links in _rewirable(materials):
        if lighting_kind(mat) == "none" or mat in sky or mat.get("q3_bounce_scaled"):
            continue
        base = bsdf.inputs["Base Color"]
        src = base.links[0].from_socket if base.is_linked else None
        scaled = nodes.new("ShaderNodeMix")
        scaled.data_type = "RGBA"
        scaled.blend_type = "MULTIPLY"
        scaled.inputs["Factor"].default_value = 1.0
        if src is not None:
            links.new(src, scaled.inputs[6])
        else:
            scaled.inputs[6].default_value = base.default_value
        scaled.inputs[7].default_value = (*scale, 1.0)
        path = nodes.new("ShaderNodeLightPath")
        pick = nodes.new("ShaderNodeMix")
        pick.data_type = "RGBA"
        links.new(path.outputs["Is Camera Ray"], pick.inputs["Factor"])
        links.new(scaled.outputs[2], pick.inputs[6])
        if src is not None:
            links.new(src, pick.inputs[7])
        else:
            pick.inputs[7].default_value = base.default_value
        links.new(pick.outputs[2], base)
        mat["q3_bounce_scaled"] = True
        changed += 1
    return changed


def relit_materials(materials=None, ambient: bool = True) -> int:
    """Vertex-lit materials: take the baked vertex colours out of the albedo (connect the
    base colour image straight to the BSDF); with `ambient`, relight's ambient term as
    emission (see `add_ambient`); what casts no shadow in q3map2 casts none
    (`shadows_as_q3map2`); the camera sees the sky's texture (`sky_as_seen`) and each
    surface light's (`emitters_as_seen`); bounced light carries the fit's bounce scale
    (`scale_bounces`). Returns how many vertex-lit materials changed."""
    emitters = surface_light_materials()  # before the ambient makes lit materials emit
    if materials is not None:
        emitters &= set(materials)
    changed = _unbake_vertex_colours(materials)
    amb = scene_ambient_irradiance() if ambient else None
    if amb is not None:
        add_ambient(amb, materials)
    scale = scene_bounce_scale()
    if scale is not None:
        scale_bounces(scale, materials)
    shadows_as_q3map2()
    sky_as_seen()
    emitters_as_seen(emitters)
    return changed


def _unbake_vertex_colours(materials=None) -> int:
    changed = 0
    for mat in materials if materials is not None else bpy.data.materials:
        bsdf = _principled(mat) if mat.node_tree is not None else None
        if bsdf is None or lighting_kind(mat) != "vertex" or not bsdf.inputs["Base Color"].is_linked:
            continue
        if mat.get("q3_bounce_scaled"):
            continue  # done before: the Mix is now scale_bounces' pick
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
