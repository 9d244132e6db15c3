"""Helpers of the Blender round-trip tests (imported by conftest.py and the tests)."""
from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

MOVE_BY = (0.6, -0.4, 0.3)  # meters, Blender axes: how far the edit moves the brightest light
# Export variants: Blender's defaults plus 'Punctual Lights', and also 'Custom Properties'.
VARIANTS = {"lights": {}, "lights+extras": {"export_extras": True}}

# Small budgets: CI has 2 cores and no GPU.
RELIGHT_FAST = ["--backend", "cpu", "--scheme", "fast", "--max-iterations", "10", "-q"]


def run(*args, **kw) -> subprocess.CompletedProcess:
    res = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    assert res.returncode == 0, f"{args} failed ({res.returncode}):\n{res.stdout}\n{res.stderr}"
    return res


def read_gltf_json(path: Path) -> dict:
    """The JSON chunk of a .glb, or a .gltf file."""
    data = Path(path).read_bytes()
    if data[:4] == b"glTF":
        n = struct.unpack("<I", data[12:16])[0]
        return json.loads(data[20:20 + n])
    return json.loads(data)


def validate(node_validator: Path, path: Path) -> dict:
    res = subprocess.run(["node", str(node_validator), str(path)], capture_output=True, text=True)
    assert res.returncode in (0, 1), res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def reset_blender(bpy) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def import_gltf(bpy, path: Path, **options) -> None:
    """A fresh scene with the file imported (Blender's default import options unless given)."""
    reset_blender(bpy)
    bpy.ops.import_scene.gltf(filepath=str(path), **options)


def gltf_to_blender(p) -> tuple[float, float, float]:
    """glTF (Y up) -> Blender (Z up), as Blender's importer maps it."""
    x, y, z = p
    return (x, -z, y)


def blender_to_gltf(p) -> tuple[float, float, float]:
    x, y, z = p
    return (x, z, -y)


_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}


def accessor(doc: dict, gltf_path: Path, index: int):
    """An accessor of a .gltf with external buffers as a float64 (or integer) numpy array,
    normalised integers mapped to [0, 1]."""
    import numpy as np
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    buf = doc["buffers"][view["buffer"]]
    data = (Path(gltf_path).parent / buf["uri"]).read_bytes()
    dtype = np.dtype(_DTYPES[acc["componentType"]])
    ncomp = _COMPONENTS[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", dtype.itemsize * ncomp)
    rows = np.lib.stride_tricks.as_strided(
        np.frombuffer(data, dtype=np.uint8, offset=start),
        shape=(acc["count"], dtype.itemsize * ncomp), strides=(stride, 1))
    out = np.ascontiguousarray(rows).view(dtype).reshape(acc["count"], ncomp)
    if acc.get("normalized"):
        return out.astype(np.float64) / np.iinfo(dtype).max
    return out.astype(np.float64) if dtype.kind == "f" else out


def triangle_count(doc: dict) -> int:
    """Triangles of every primitive of every mesh that a node uses."""
    used = [n["mesh"] for n in doc.get("nodes", []) if "mesh" in n]
    total = 0
    for m in used:
        for p in doc["meshes"][m]["primitives"]:
            assert p.get("mode", 4) == 4
            total += doc["accessors"][p["indices"]]["count"] // 3
    return total


def light_nodes(doc: dict) -> dict[str, tuple[dict, dict]]:
    """name -> (node, KHR light) for the nodes that carry a KHR_lights_punctual light."""
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    out = {}
    for n in doc.get("nodes", []):
        ext = n.get("extensions", {}).get("KHR_lights_punctual")
        if ext is not None:
            out[n["name"]] = (n, lights[ext["light"]])
    return out
