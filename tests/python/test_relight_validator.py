"""The Khronos glTF-Validator accepts what `q3gltf relight` writes: the bundled sample
(converted, then relit, as .gltf and .glb, beside the input and in another folder) and a
real map (oa_dm1, small budget, on whatever wgpu adapter the machine has: lavapipe in
CI)."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _run(*args: str) -> None:
    res = subprocess.run(args, capture_output=True, text=True)
    assert res.returncode == 0, f"{args} failed:\n{res.stderr}"


def _validate(node_validator: Path, files: list[Path]) -> list[dict]:
    res = subprocess.run(["node", str(node_validator), *map(str, files)], capture_output=True, text=True)
    assert res.returncode in (0, 1), res.stderr
    return [json.loads(line) for line in res.stdout.splitlines() if line.strip()]


def test_relit_outputs_are_valid(q3gltf, baseoa, node_validator, tmp_path):
    sample = tmp_path / "sample.gltf"
    _run(str(q3gltf), "convert", str(REPO / "samples/sample/maps/sample.bsp"), "-q", "-o", str(sample))
    outs = []
    for folder in (tmp_path, tmp_path / "elsewhere"):
        # In another folder the output is self-contained (copies of the textures and the
        # buffer, or everything embedded in the .glb): validate.mjs refuses "../" URIs.
        folder.mkdir(exist_ok=True)
        for ext in ("gltf", "glb"):
            out = folder / f"sample.relit.{ext}"
            _run(str(q3gltf), "relight", str(sample), "-o", str(out), "--backend", "cpu", "--scheme", "fast", "-q")
            outs.append(out)
    dm1 = tmp_path / "oa_dm1.glb"
    _run(str(q3gltf), "convert", "oa_dm1", "--game-dir", str(baseoa), "-q", "-o", str(dm1))
    dm1_out = tmp_path / "oa_dm1.relit.glb"
    _run(str(q3gltf), "relight", str(dm1), "-o", str(dm1_out), "--backend", "wgpu", "--subdivide", "off",
         "--init", "grid:2", "--scheme", "fast", "--max-iterations", "4", "-q")
    outs.append(dm1_out)
    results = _validate(node_validator, outs)
    assert len(results) == len(outs)
    for out, r in zip(outs, results):
        assert r["errors"] == 0, f"{out}: {r}"
        doc = out.read_bytes()
        assert b"KHR_lights_punctual" in doc
