"""`q3gltf info --json` against bsp_tool, an independent Python BSP parser.

For every map of pak1-maps.pk3 and pak6-patch088.pk3 (88 real OpenArena IBSP v46 maps)
the lump counts that q3gltf reports must equal what bsp_tool reads from the same file:
draw vertices, draw indices, surfaces per type, 128x128 lightmap pages, shaders, models,
entities, planes, nodes, leafs and brushes. Exact equality: a count that is off means the
lump directory or a struct size is mis-read on one side, and everything the converter
builds on top of it (geometry, materials, lightmap atlas) would be wrong too.

bsp_tool 0.7.0 facts this relies on (found by experiment on pak1/oa_dm1):
  * ``bsp_tool.load_bsp(path)`` auto-detects IBSP v46 as ``IdTechBsp`` with branch script
    ``bsp_tool.branches.id_software.quake3``; ``bsp.file_magic == b"IBSP"``,
    ``bsp.version == 46``. The Bsp is a context manager (its lumps read lazily from the
    open file, which ``__exit__`` closes).
  * Lumps are attributes named after ``quake3.LUMP`` (Q3 source name in brackets):
      ENTITIES (0, entities)        -> shared.Entities, a list of dicts (line-based parser)
      TEXTURES (1, shaders)         -> Texture(name, flags.surface, flags.contents), 72 B
      PLANES (2)                    -> Plane, 16 B
      NODES (3)                     -> Node, 36 B
      LEAVES (4, leafs)             -> Leaf, 48 B
      LEAF_FACES (5, leafsurfaces), LEAF_BRUSHES (6) -> ints
      MODELS (7)                    -> Model(bounds, first_face, num_faces, ...), 40 B
      BRUSHES (8), BRUSH_SIDES (9)  -> 12 B, 8 B
      VERTICES (10, drawverts)      -> Vertex(position, uv.texture, uv.lightmap, normal,
                                       colour), 44 B
      INDICES (11, drawindexes)     -> ints ("meshverts")
      EFFECTS (12, fogs)            -> Effect, 72 B
      FACES (13, surfaces)          -> Face, 104 B; ``face.type`` is the enum
                                       ``quake3.FaceType``: BAD=0, PLANAR=1 (MST_PLANAR),
                                       PATCH=2, TRIANGLE_SOUP=3 (MST_TRIANGLE_SOUP, "mesh"),
                                       FLARE=4, FOLIAGE=5 (not Q3); ``.value`` is the int
      LIGHTMAPS (14)                -> Lightmap, one per 128x128x3 = 49152 B page
      LIGHT_GRID (15), VISIBILITY (16)
  * Entry counts are ``lump_header.length // struct_size``; a lump of length 0 is not
    mounted at all (the attribute is missing), hence ``getattr(bsp, NAME, ())``.
    pak1/oa_ctf2 has no LIGHTMAPS lump (every surface is vertex-lit, lightmap index -3).
  * A lump that fails to parse (e.g. a face type outside the enum) falls back to raw
    bytes and is recorded in ``bsp.loading_errors``; the test refuses to compare then.
On all 88 maps these counts were checked against a hand-written header reader (lump
length / struct size, raw surface-type ints): they agree, and no lump length has a
remainder. bsp_tool's entity count equals the number of '{' in the entity lump there.
"""
from __future__ import annotations

import collections
import json
import subprocess

import bsp_tool
import pytest
from bsp_tool.branches.id_software import quake3

# q3gltf's surface-type keys, by Q3 surface type (mapSurfaceType_t) value.
SURFACE_KEYS = {1: "polygon", 2: "patch", 3: "mesh", 4: "flare"}
EXPECTED_KEYS = {"file", "format", "version", "vertices", "indices", "surfaces",
                 "lightmap_pages", "shaders", "models", "entities", "planes", "nodes",
                 "leafs", "brushes"}
LUMPS_USED = ("ENTITIES", "TEXTURES", "PLANES", "NODES", "LEAVES", "MODELS", "BRUSHES",
              "VERTICES", "INDICES", "FACES", "LIGHTMAPS")


def reference_counts(path) -> dict:
    """What `q3gltf info --json` must say about PATH, computed with bsp_tool."""
    with bsp_tool.load_bsp(str(path)) as bsp:
        assert bsp.branch is quake3, f"bsp_tool chose branch {bsp.branch.__name__}"
        errors = {k: v for k, v in bsp.loading_errors.items() if k in LUMPS_USED}
        assert not errors, f"bsp_tool failed to parse lumps: {errors!r}"

        def count(lump: str) -> int:
            return len(getattr(bsp, lump, ()))

        surfaces = {"polygon": 0, "patch": 0, "mesh": 0, "flare": 0, "other": 0}
        types = collections.Counter(face.type.value for face in getattr(bsp, "FACES", ()))
        for value, n in types.items():
            surfaces[SURFACE_KEYS.get(value, "other")] += n
        return {
            "format": bsp.file_magic.decode("ascii"),
            "version": bsp.version,
            "vertices": count("VERTICES"),
            "indices": count("INDICES"),
            "surfaces": surfaces,
            "lightmap_pages": count("LIGHTMAPS"),
            "shaders": count("TEXTURES"),
            "models": count("MODELS"),
            "entities": count("ENTITIES"),
            "planes": count("PLANES"),
            "nodes": count("NODES"),
            "leafs": count("LEAVES"),
            "brushes": count("BRUSHES"),
        }


def run_info(q3gltf, path) -> dict:
    proc = subprocess.run([str(q3gltf), "info", str(path), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, (
        f"q3gltf info exited {proc.returncode}\nstderr: {proc.stderr.strip()}")
    try:
        info = json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        problem = f"q3gltf info --json printed invalid JSON ({exc}):\n{proc.stdout[:2000]!r}"
    else:
        problem = None
    if problem:
        pytest.fail(problem, pytrace=False)
    assert isinstance(info, dict), f"expected one JSON object, got {type(info).__name__}"
    return info


def test_info_matches_bsp_tool(q3gltf, bsp_map):
    info = run_info(q3gltf, bsp_map.path)
    missing = EXPECTED_KEYS - info.keys()
    assert not missing, f"info --json lacks keys {sorted(missing)}: {info}"
    assert isinstance(info["file"], str) and info["file"].endswith(bsp_map.path.name), info["file"]
    assert isinstance(info["surfaces"], dict)
    assert set(info["surfaces"]) == {"polygon", "patch", "mesh", "flare", "other"}, info["surfaces"]

    expected = reference_counts(bsp_map.path)
    actual = {k: info[k] for k in expected}
    assert actual == expected
