"""Show a physically lit render the way the game shows its lightmaps: a compositor setup
for Blender (5.0) that turns Cycles' render passes into the engine's picture.

The game (ioquake3's classic renderer) does not show `albedo x light`: it multiplies the
texture's sRGB bytes `T` by the light `e` clamped at 1 keeping its hue, and the screen
turns that display value into light through the sRGB transfer function `D`:

    pixel = D(T x L),   T = D^-1(albedo),   L = e / max(1, max channel of e)

Cycles gives every pixel's albedo (Diffuse Color pass) and the light that reached it
(Diffuse Direct + Indirect, and relight's ambient as Emission / albedo), so the
compositor can apply exactly that per pixel; pixels without a diffuse surface (sky,
pure emitters, background) keep Cycles' own colour. The scene keeps its physical lights
(relight's default `--look lightmap`, the mapper's lights), and the picture is the
game's. Measured in `make render` against the game's own frames (README, "Blender").

Usage, after importing a relit glTF (inside Blender, or with `import bpy`):

    import lightmap_preview, game_display
    lightmap_preview.relit_materials()   # vertex colours out, ambient as emission
    game_display.setup()                 # passes on, compositor node group set

Rendering with the compositor on (the default) then writes the game's picture.

A map compiled with q3map2's `-gamma G` stores its light `e` as `2^ob (e / 2^ob)^(1/G)`
(`ob` the overbright bits): the game shows that, not `e`. Where the relit file states the
gamma its lightmaps were read through (the lit materials' `q3_lightmap_gamma`, recorded
by the compile or estimated by relight), `setup` applies it before the engine's clamp.
"""
from __future__ import annotations

import bpy

from node_math import math as _math, srgb_decode, srgb_encode

GROUP_NAME = "q3gltf game display"


def stated_gamma() -> tuple[float, int]:
    """The gamma and overbright bits the file's lit materials state (custom properties
    `q3_lightmap_gamma`, `q3_overbright_bits`, from the glTF's material extras): the
    largest gamma stated, 1 and 2 where none is."""
    gammas = [float(m["q3_lightmap_gamma"]) for m in bpy.data.materials if "q3_lightmap_gamma" in m]
    bits = [int(m["q3_overbright_bits"]) for m in bpy.data.materials if "q3_overbright_bits" in m]
    return (max(gammas) if gammas else 1.0, max(bits) if bits else 2)


def setup(scene=None, denoise: bool = True, gamma: float | None = None) -> bpy.types.NodeTree:
    """Turns on the passes it needs on every view layer and sets the scene's compositor to
    the game display group (made anew); the render engine becomes Cycles. With `denoise`,
    the diffuse light (Direct + Indirect, the noisy part) goes through the compositor's
    Denoise node (OpenImageDenoise, HDR) before the formula. `gamma`: the compile's, as
    its lightmaps store light (default: what the materials state, `stated_gamma`).
    Returns the group."""
    scene = scene or bpy.context.scene
    stated, bits = stated_gamma()
    gamma = stated if gamma is None else float(gamma)
    full = float(2 ** bits)
    scene.render.engine = "CYCLES"  # the passes below are Cycles'
    for vl in scene.view_layers:
        vl.use_pass_diffuse_color = True
        vl.use_pass_diffuse_direct = True
        vl.use_pass_diffuse_indirect = True
        vl.use_pass_emit = True
    old = bpy.data.node_groups.get(GROUP_NAME)
    if old is not None:
        bpy.data.node_groups.remove(old)
    tree = bpy.data.node_groups.new(GROUP_NAME, "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    nodes, links = tree.nodes, tree.links
    rl = nodes.new("CompositorNodeRLayers")
    rl.scene = scene

    def channels(name):
        sep = nodes.new("CompositorNodeSeparateColor")
        links.new(rl.outputs[name], sep.inputs[0])
        return [sep.outputs[i] for i in range(3)]

    def separate(socket):
        sep = nodes.new("CompositorNodeSeparateColor")
        links.new(socket, sep.inputs[0])
        return [sep.outputs[i] for i in range(3)]

    col, emit, comb = (channels(n) for n in ("Diffuse Color", "Emission", "Image"))
    # The diffuse light that reached each pixel (Cycles' passes leave the albedo out).
    add = nodes.new("ShaderNodeMix")
    add.data_type = "RGBA"
    add.blend_type = "ADD"
    add.inputs["Factor"].default_value = 1.0
    links.new(rl.outputs["Diffuse Direct"], add.inputs[6])
    links.new(rl.outputs["Diffuse Indirect"], add.inputs[7])
    light = add.outputs[2]
    if denoise:
        dn = nodes.new("CompositorNodeDenoise")
        links.new(light, dn.inputs["Image"])
        dn.inputs["HDR"].default_value = True
        light = dn.outputs["Image"]
    light = separate(light)
    # e per channel: the diffuse light, plus the ambient's emission over the albedo
    # (Math's divide gives 0 where the albedo is 0).
    e = [_math(nodes, links, "ADD", light[c], _math(nodes, links, "DIVIDE", emit[c], col[c])) for c in range(3)]
    if gamma != 1.0:
        # What the lightmap stores and the game shows: 2^ob (e / 2^ob)^(1/G).
        e = [_math(nodes, links, "MULTIPLY", _math(nodes, links, "POWER", _math(nodes, links, "DIVIDE", e[c], full), 1.0 / gamma), full) for c in range(3)]
    peak = _math(nodes, links, "MAXIMUM", _math(nodes, links, "MAXIMUM", e[0], e[1]), e[2])
    scale = _math(nodes, links, "DIVIDE", 1.0, _math(nodes, links, "MAXIMUM", peak, 1.0))
    diffuse = _math(nodes, links, "GREATER_THAN", _math(nodes, links, "ADD", _math(nodes, links, "ADD", col[0], col[1]), col[2]), 1e-6)
    out = nodes.new("CompositorNodeCombineColor")
    for c in range(3):
        shown = srgb_decode(nodes, links, _math(nodes, links, "MULTIPLY", srgb_encode(nodes, links, col[c]),
                                                _math(nodes, links, "MULTIPLY", e[c], scale)))
        # Surfaces without a diffuse albedo keep Cycles' colour.
        pick = _math(nodes, links, "ADD", comb[c], _math(nodes, links, "MULTIPLY", diffuse, _math(nodes, links, "SUBTRACT", shown, comb[c])))
        links.new(pick, out.inputs[c])
    group_out = nodes.new("NodeGroupOutput")
    links.new(out.outputs[0], group_out.inputs[0])
    scene.compositing_node_group = tree
    scene.render.use_compositing = True
    return tree
