"""`q3gltf bake` checked from outside: a point light over a plane, baked into its lightmap
and read back with an independent EXR reader (OpenEXR's Python binding), texel by texel
against the analytic irradiance.

The scene is written here from scratch (not by convert): a 4 m x 4 m floor (y = 0,
normal +y) whose TEXCOORD_1 puts its corners on the centres of texels (0, 0) and
(31, 31) of a 32 x 32 lightmap, as q3map2 does, and one point light 1 m above it.

Expected value of texel (i, j), in the lightmap's linear units e = E / pi
(CONVENTIONS.md): q3map2 samples a luxel one Quake unit (0.0254 m) above the surface,
so at x = (i / 31 - 1/2) 4 m, z = (j / 31 - 1/2) 4 m, y = 0.0254 m,

    E = I (h - 0.0254) / r^3,   r = |light - sample|,   I = cd / 683  [W/sr]

(every r here is above q3map2's 16-unit floor of the inverse square, and every E above
its one-byte falloff cut). Texels outside the quad stay uncovered: alpha 0.
"""
from __future__ import annotations

import base64
import json
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

N = 32            # lightmap texels per side
SIZE_M = 4.0      # floor side
HEIGHT_M = 1.0    # light above the floor
CANDELA = 6830.0  # 10 W/sr
OFFSET_M = 0.0254 # q3map2's sample offset: one Quake unit


def png_grey(path: Path, w: int, h: int, v: int) -> None:
    """A minimal RGBA8 PNG (no imaging library needed)."""
    raw = b"".join(b"\x00" + bytes([v, v, v, 255]) * w for _ in range(h))
    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def plane_scene(d: Path) -> Path:
    h = SIZE_M / 2
    # Corners counter-clockwise seen from +y; lightmap texel centres 0.5 and N - 0.5.
    pos = [(-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h)]
    uv1 = [((0.5 + (x + h) / SIZE_M * (N - 1)) / N, (0.5 + (z + h) / SIZE_M * (N - 1)) / N) for x, _, z in pos]
    blob = b"".join(struct.pack("<3f", *p) for p in pos)
    blob += b"".join(struct.pack("<3f", 0, 1, 0) for _ in pos)
    blob += b"".join(struct.pack("<2f", 0, 0) for _ in pos)
    blob += b"".join(struct.pack("<2f", *uv) for uv in uv1)
    blob += struct.pack("<6I", 0, 1, 2, 0, 2, 3)
    png_grey(d / "lm.png", N, N, 64)
    views = [(0, 48, 34962), (48, 48, 34962), (96, 32, 34962), (128, 32, 34962), (160, 24, 34963)]
    gltf = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "color": [1, 1, 1], "intensity": CANDELA}]}},
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": o, "byteLength": n, "target": t} for o, n, t in views],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-h, 0, -h], "max": [h, 0, h]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 4, "componentType": 5125, "count": 6, "type": "SCALAR"},
        ],
        "images": [{"uri": "lm.png"}],
        "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}],
        "textures": [{"source": 0, "sampler": 0}],
        "materials": [{"name": "floor", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1]},
                       "occlusionTexture": {"index": 0, "texCoord": 1},
                       "extras": {"q3_lighting": "lightmap", "q3_overbright_bits": 2}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2, "TEXCOORD_1": 3}, "indices": 4, "material": 0}]}],
        "nodes": [{"mesh": 0, "name": "floor"},
                  {"name": "light", "translation": [0.3, HEIGHT_M, -0.2], "extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0,
    }
    p = d / "plane.gltf"
    p.write_text(json.dumps(gltf))
    return p


def read_rgba(path: Path) -> np.ndarray:
    with OpenEXR.File(str(path)) as f:
        px = f.channels()["RGBA"].pixels
    return np.asarray(px, dtype=np.float64)


@pytest.mark.parametrize("half", [False, True])
def test_point_light_over_a_plane_matches_the_analytic_irradiance(q3gltf: Path, tmp_path: Path, half: bool) -> None:
    gltf = plane_scene(tmp_path)
    out = tmp_path / "bake"
    args = [str(q3gltf), "bake", str(gltf), "-o", str(out), "--backend", "cpu", "-q"] + (["--half"] if half else [])
    subprocess.run(args, check=True, capture_output=True, timeout=120)
    report = json.loads((out / "bake.json").read_text())
    assert len(report["pages"]) == 1 and report["lights"] == 1
    name = report["pages"][0]["name"]
    relit = read_rgba(out / f"{name}.relit.exr")
    assert relit.shape == (N, N, 4)
    assert np.all(relit[..., 3] == 1.0), "every texel of the page samples the floor"
    # The analytic value at each texel's sample point.
    lx, ly, lz = 0.3, HEIGHT_M, -0.2
    i = np.arange(N)
    x = (i / (N - 1) - 0.5) * SIZE_M
    X, Z = np.meshgrid(x, x)  # rows: v (z), columns: u (x)
    r = np.sqrt((lx - X) ** 2 + (ly - OFFSET_M) ** 2 + (lz - Z) ** 2)
    e = CANDELA / 683.0 * (ly - OFFSET_M) / r ** 3 / np.pi
    tol = 2e-3 if half else 2e-5
    for c in range(3):
        rel = np.abs(relit[..., c] - e) / e
        assert rel.max() < tol, f"channel {c}: largest relative difference {rel.max():.2e}"
    # The original (64 everywhere) decodes to the middle of its byte's interval.
    orig = read_rgba(out / f"{name}.original.exr")
    assert np.allclose(orig[..., :3], 64.5 * 4 / 255, rtol=1e-3 if half else 1e-6)
    # The residual is the distance outside [64, 65) / 255 * 4, signed.
    res = read_rgba(out / f"{name}.residual.exr")
    lo, hi = 64 * 4 / 255, 65 * 4 / 255
    want = e - np.clip(e, lo, hi)
    assert np.allclose(res[..., 0], want, atol=4e-3 if half else 1e-5)
    assert (res[..., 0] > 0).any() and (res[..., 0] < 0).any(), "a light this bright is above the grey in the middle, below at the rim"
