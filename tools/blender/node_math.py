"""Node-graph arithmetic shared by the material scripts (lightmap_preview.py) and the
compositor group (game_display.py): scalar Math nodes, and the sRGB transfer function and
its inverse built from them. `ShaderNodeMath` works in shader and compositor trees alike
(Blender 5.0)."""
from __future__ import annotations


def math(nodes, links, op, a, b=None):
    """A Math node `op(a, b)`; each operand a socket or a number. Returns its output."""
    n = nodes.new("ShaderNodeMath")
    n.operation = op
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            n.inputs[i].default_value = float(v)
        else:
            links.new(v, n.inputs[i])
    return n.outputs[0]


def srgb_decode(nodes, links, c):
    """D per scalar: `c / 12.92` up to 0.04045, `((c + 0.055) / 1.055)^2.4` above
    (display value -> light)."""
    low = math(nodes, links, "DIVIDE", c, 12.92)
    high = math(nodes, links, "POWER", math(nodes, links, "DIVIDE", math(nodes, links, "ADD", c, 0.055), 1.055), 2.4)
    return math(nodes, links, "ADD", low, math(nodes, links, "MULTIPLY", math(nodes, links, "GREATER_THAN", c, 0.04045),
                                                math(nodes, links, "SUBTRACT", high, low)))


def srgb_encode(nodes, links, x):
    """D^-1 per scalar: `12.92 x` up to 0.0031308, `1.055 x^(1/2.4) - 0.055` above (x
    clamped to [0, 1] first; light -> display value)."""
    x = math(nodes, links, "MINIMUM", math(nodes, links, "MAXIMUM", x, 0.0), 1.0)
    low = math(nodes, links, "MULTIPLY", x, 12.92)
    high = math(nodes, links, "SUBTRACT", math(nodes, links, "MULTIPLY", math(nodes, links, "POWER", x, 1.0 / 2.4), 1.055), 0.055)
    return math(nodes, links, "ADD", low, math(nodes, links, "MULTIPLY", math(nodes, links, "GREATER_THAN", x, 0.0031308),
                                                math(nodes, links, "SUBTRACT", high, low)))
