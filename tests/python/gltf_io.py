"""Reading what q3gltf writes without any glTF library: GLB chunks, accessors (any stride),
embedded PNG sizes, and the filtering footprint of lightmap charts. Shared by the Python
and Blender suites (numpy only)."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np


def read_glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<3I", data, 0)
    assert magic == 0x46546C67 and version == 2 and total == len(data)
    doc, binary, off = None, b"", 12
    while off < total:
        n, kind = struct.unpack_from("<2I", data, off)
        body = data[off + 8: off + 8 + n]
        if kind == 0x4E4F534A:
            doc = json.loads(body)
        elif kind == 0x004E4942:
            binary = body
        off += 8 + n
    assert doc is not None
    return doc, binary


def accessor(doc: dict, binary: bytes, index: int) -> np.ndarray:
    a = doc["accessors"][index]
    v = doc["bufferViews"][a["bufferView"]]
    dtype = {5126: "<f4", 5125: "<u4", 5123: "<u2", 5121: "u1"}[a["componentType"]]
    ncomp = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a["type"]]
    item = np.dtype(dtype).itemsize * ncomp
    stride = v.get("byteStride", item)
    start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
    rows = [np.frombuffer(binary, dtype, ncomp, start + k * stride) for k in range(a["count"])]
    return np.array(rows).reshape(a["count"], ncomp) if ncomp > 1 else np.array(rows).reshape(-1)


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def image_bytes(doc: dict, binary: bytes, index: int) -> bytes:
    v = doc["bufferViews"][doc["images"][index]["bufferView"]]
    return binary[v.get("byteOffset", 0): v.get("byteOffset", 0) + v["byteLength"]]


def charts_sharing_filtered_texels(doc: dict, binary: bytes, image: int) -> tuple[int, int]:
    """For the primitives whose lightmap (occlusionTexture on TEXCOORD_1) is image `image`:
    how many texels bilinear filtering inside two different charts would read, and the
    number of charts. A chart is a connected set of triangles of one primitive (sharing a
    vertex, or a vertex at the same atlas point); filtering at a point reads the texels
    whose centres lie within 1 of it on both axes."""
    w, h = png_size(image_bytes(doc, binary, image))
    owner = np.full((h, w), -1, dtype=np.int64)
    shared, charts = 0, 0
    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            m = doc["materials"][p["material"]] if "material" in p else {}
            occ = m.get("occlusionTexture")
            if occ is None or occ.get("texCoord") != 1 or doc["textures"][occ["index"]]["source"] != image:
                continue
            uv = accessor(doc, binary, p["attributes"]["TEXCOORD_1"]).astype(np.float64) * [w, h]
            tris = accessor(doc, binary, p["indices"]).reshape(-1, 3)
            parent = list(range(len(uv)))

            def find(i: int) -> int:
                while parent[i] != i:
                    parent[i] = parent[parent[i]]
                    i = parent[i]
                return i
            at: dict[tuple[float, float], int] = {}
            for i, u in enumerate(map(tuple, uv)):
                parent[find(i)] = find(at.setdefault(u, i))
            for a, b, c in tris:
                parent[find(b)] = find(a)
                parent[find(c)] = find(a)
            ids: dict[int, int] = {}
            for t in tris:
                q = uv[t]
                if abs(np.cross(q[1] - q[0], q[2] - q[0])) < 1e-9:
                    continue
                chart = ids.setdefault(find(int(t[0])), charts + len(ids))
                lo, hi = q.min(axis=0), q.max(axis=0)
                for y in range(max(0, int(np.floor(lo[1] - 1.5))), min(h, int(np.ceil(hi[1] + 1.5)))):
                    for x in range(max(0, int(np.floor(lo[0] - 1.5))), min(w, int(np.ceil(hi[0] + 1.5)))):
                        if not _triangle_meets_square(q, np.array([x + 0.5, y + 0.5]), 1.0 - 1e-3):
                            continue
                        if owner[y, x] == -1:
                            owner[y, x] = chart
                        elif owner[y, x] != chart:
                            shared += 1
            charts += len(ids)
    return shared, charts


def _triangle_meets_square(q: np.ndarray, c: np.ndarray, half: float) -> bool:
    square = c + half * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
    axes = [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
    for k in range(3):
        e = q[(k + 1) % 3] - q[k]
        axes.append(np.array([-e[1], e[0]]))
    for ax in axes:
        t, s = q @ ax, square @ ax
        if not (t.min() < s.max() and s.min() < t.max()):
            return False
    return True
