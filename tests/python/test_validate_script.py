"""Self-test of tests/node/validate.mjs, the glTF-Validator driver that test_validator.py
relies on, on tiny hand-made assets (no q3gltf binary or game data needed).

A harness that always said "0 errors" would make test_validator.py worthless, so this
checks both directions: valid .gltf (external .bin and a PNG texture in a subdirectory,
with a percent-encoded file name) and .glb pass with no issue at all, while broken files
(wrong accessor max, dangling index reference, truncated GLB, missing buffer, a URI
escaping the asset's directory, a file that does not exist) are reported as errors,
all within a single node invocation, one JSON line per file in argument order.
"""
from __future__ import annotations

import json
import struct
import subprocess
import zlib
from pathlib import Path

import pytest

POSITIONS = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
UVS = struct.pack("<6f", 0, 0, 1, 0, 0, 1)
INDICES = struct.pack("<3H", 0, 1, 2) + b"\0\0"
BUFFER = POSITIONS + UVS + INDICES  # 36 + 24 + 8 bytes


def png_2x2() -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    rows = b"".join(b"\0" + bytes([255, 0, 0, 0, 255, 0]) for _ in range(2))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">2I5B", 2, 2, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def gltf_doc(buffer_uri: str | None, image: dict | None = None) -> dict:
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                    "indices": 2, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987}],
        "images": [image or {"uri": "tex/red%20pixel.png"}],
        "buffers": [{"byteLength": len(BUFFER)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36, "target": 34962},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24, "target": 34962},
            {"buffer": 0, "byteOffset": 60, "byteLength": 6, "target": 34963},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }
    if buffer_uri is not None:
        doc["buffers"][0]["uri"] = buffer_uri
    return doc


def glb_bytes(doc: dict, bin_chunk: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    bin_chunk += b"\0" * (-len(bin_chunk) % 4)
    total = 12 + 8 + len(js) + 8 + len(bin_chunk)
    return (struct.pack("<3I", 0x46546C67, 2, total)
            + struct.pack("<2I", len(js), 0x4E4F534A) + js
            + struct.pack("<2I", len(bin_chunk), 0x004E4942) + bin_chunk)


@pytest.fixture(scope="module")
def reports(tmp_path_factory, node_validator) -> dict[str, dict]:
    d: Path = tmp_path_factory.mktemp("toys")
    (d / "tex").mkdir()
    (d / "tex" / "red pixel.png").write_bytes(png_2x2())
    (d / "tri.bin").write_bytes(BUFFER)
    files: dict[str, Path] = {}

    def put(name: str, doc: dict) -> None:
        files[name] = d / name
        files[name].write_text(json.dumps(doc))

    put("ok.gltf", gltf_doc("tri.bin"))
    bad = gltf_doc("tri.bin")
    bad["accessors"][0]["max"] = [5, 5, 5]
    bad["meshes"][0]["primitives"][0]["indices"] = 7
    put("bad.gltf", bad)
    put("missing_bin.gltf", gltf_doc("nope.bin"))
    (d / "sub").mkdir()
    files["escape.gltf"] = d / "sub" / "escape.gltf"
    files["escape.gltf"].write_text(json.dumps(gltf_doc("../tri.bin", {"uri": "../tex/red%20pixel.png"})))
    png = png_2x2()
    glb_bin = BUFFER + png + b"\0" * (-len(png) % 4)
    glb_doc = gltf_doc(None, {"bufferView": 3, "mimeType": "image/png"})
    glb_doc["buffers"][0]["byteLength"] = len(glb_bin)
    glb_doc["bufferViews"].append({"buffer": 0, "byteOffset": 68, "byteLength": len(png)})
    files["ok.glb"] = d / "ok.glb"
    files["ok.glb"].write_bytes(glb_bytes(glb_doc, glb_bin))
    files["truncated.glb"] = d / "truncated.glb"
    files["truncated.glb"].write_bytes(files["ok.glb"].read_bytes()[:60])
    files["absent.gltf"] = d / "absent.gltf"

    names = list(files)
    proc = subprocess.run(["node", str(node_validator), *[str(files[n]) for n in names]],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["file"] for r in lines] == [str(files[n]) for n in names], proc.stdout
    return dict(zip(names, lines))


@pytest.mark.parametrize("name", ["ok.gltf", "ok.glb"])
def test_valid_assets_are_clean(reports, name):
    rep = reports[name]
    assert (rep["errors"], rep["warnings"], rep["infos"], rep["hints"]) == (0, 0, 0, 0), rep


@pytest.mark.parametrize("name, code", [
    ("bad.gltf", "ACCESSOR_MAX_MISMATCH"),
    ("bad.gltf", "UNRESOLVED_REFERENCE"),
    ("missing_bin.gltf", "IO_ERROR"),
    ("escape.gltf", "IO_ERROR"),
    ("truncated.glb", None),
    ("absent.gltf", "FATAL"),
])
def test_broken_assets_are_errors(reports, name, code):
    rep = reports[name]
    assert rep["errors"] > 0, rep
    assert rep["messages"], rep
    assert all({"code", "message"} <= m.keys() for m in rep["messages"])
    if code:
        assert code in {m["code"] for m in rep["messages"]}, rep


def test_escape_is_refused_not_read(reports):
    messages = " ".join(m["message"] for m in reports["escape.gltf"]["messages"])
    assert "refusing" in messages, messages
    assert reports["escape.gltf"]["errors"] == 2  # the buffer and the image
