"""Relight's subdivision judged by pymeshlab, an independent mesh library.

`q3gltf relight IN --write-mesh OUT.ply --subdivide B` writes the mesh relight fits on:
positions in meters, the lightmap UV in texels as the texture coordinate, the material as
the vertex quality. On real inputs (the converted sample and oa_dm1), per material:
- the total surface area and the lightmap-UV area are preserved;
- every input triangle is tiled by its pieces (areas add up; no edge shared by more than
  two pieces of one triangle: no fold, no duplicate), so the only non-manifold edges are
  where the input's own surfaces touch or overlap; and the boundary never grows: no hole
  or crack appears (splitting may close a T-junction, never open one);
- no edge is longer than the bound (meters, or one lightmap texel), unless the report
  says the vertex budget stopped the refinement.
Vertices are merged by exact position first (the mesh stores one vertex per primitive
corner); materials are judged separately because different surfaces may touch (a pillar
standing on a floor shares a line with it once the floor is split along that line)."""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pymeshlab
import pytest

REPO = Path(__file__).resolve().parents[2]


def _run(*args: str) -> str:
    res = subprocess.run(args, capture_output=True, text=True)
    assert res.returncode == 0, f"{args} failed:\n{res.stderr}"
    return res.stdout


def _load(ply: Path):
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(ply))
    m = ms.current_mesh()
    assert m.has_vertex_tex_coord() and m.has_vertex_scalar()
    assert m.has_face_scalar()
    return m.vertex_matrix(), m.face_matrix(), m.vertex_tex_coord_matrix(), m.vertex_scalar_array(), m.face_scalar_array().astype(np.int64)


def _measures(v: np.ndarray, f: np.ndarray, uv: np.ndarray) -> dict:
    """pymeshlab's measures of one material's faces: area, lightmap-UV area, non-manifold
    edges, and boundary length."""
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    verts, faces, uvs = v[used], remap[f], uv[used]
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=verts, face_matrix=faces))
    area = ms.get_geometric_measures()["surface_area"]
    ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(1e-7))
    topo = ms.get_topological_measures()
    uvm = pymeshlab.MeshSet()
    uvm.add_mesh(pymeshlab.Mesh(vertex_matrix=np.c_[uvs, np.zeros(len(uvs))], face_matrix=faces))
    uv_area = uvm.get_geometric_measures()["surface_area"] if len(faces) else 0.0
    # Boundary length on the merged mesh: a crack or hole adds boundary, splitting an edge
    # keeps its length, closing a T-junction removes some.
    mm = ms.current_mesh()
    mv, mf = mm.vertex_matrix(), mm.face_matrix()
    e = np.concatenate([mf[:, [0, 1]], mf[:, [1, 2]], mf[:, [2, 0]]])
    e.sort(axis=1)
    u, counts = np.unique(e, axis=0, return_counts=True)
    b = u[counts == 1]
    boundary = float(np.linalg.norm(mv[b[:, 0]] - mv[b[:, 1]], axis=1).sum()) if len(b) else 0.0
    return {"area": area, "uv_area": uv_area, "non_manifold": topo["non_two_manifold_edges"], "boundary": boundary}


def _source_checks(v: np.ndarray, f: np.ndarray, src: np.ndarray, degenerate: np.ndarray, where: str) -> None:
    """Every input triangle is tiled by its pieces: their areas add up to its area (checked
    against the input by the caller) and no edge is shared by more than two pieces of one
    input triangle (a fold or a duplicated piece). Non-manifold edges between pieces of
    different input triangles come from the input's own geometry: two surfaces touching
    along a line (a pillar on a floor), or overlapping coplanar faces. Degenerate input
    triangles (zero area: real maps have them, e.g. q3map2's T-junction fixes) are split
    along with their neighbours into zero-area pieces on one line; they are left out."""
    keep = ~degenerate[src]
    f, src = f[keep], src[keep]
    _, vid = np.unique(v, axis=0, return_inverse=True)
    vid = vid.ravel()
    tri = vid[f]
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    edges.sort(axis=1)
    keyed = np.c_[np.tile(src, 3), edges]
    _, counts = np.unique(keyed, axis=0, return_counts=True)
    assert counts.max(initial=0) <= 2, f"{where}: {(counts > 2).sum()} edges are shared by more than two pieces of one input triangle"


def _areas_by_source(v: np.ndarray, f: np.ndarray, src: np.ndarray, n: int) -> np.ndarray:
    a = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    return np.bincount(src, weights=a, minlength=n)


def _longest(v: np.ndarray, f: np.ndarray) -> float:
    e = np.concatenate([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]], v[f[:, 0]] - v[f[:, 2]]])
    return float(np.sqrt((e ** 2).sum(axis=1)).max()) if len(e) else 0.0


def _check(q3gltf: Path, scene: Path, bound: str, tmp: Path) -> None:
    before, after = tmp / "before.ply", tmp / "after.ply"
    _run(str(q3gltf), "relight", str(scene), "--write-mesh", str(before), "--subdivide", "off")
    out = _run(str(q3gltf), "relight", str(scene), "--write-mesh", str(after), "--subdivide", bound)
    assert "vertex budget reached" not in out, out
    v0, f0, uv0, q0, s0 = _load(before)
    v1, f1, uv1, q1, s1 = _load(after)
    assert len(f1) > len(f0), "nothing was subdivided"
    assert np.array_equal(s0, np.arange(len(f0))), "the input's faces are their own sources"
    a0, a1 = _areas_by_source(v0, f0, s0, len(f0)), _areas_by_source(v1, f1, s1, len(f0))
    assert np.allclose(a1, a0, rtol=1e-4, atol=1e-9), f"{scene.name}: an input triangle's pieces do not add up to its area"
    _source_checks(v1, f1, s1, a0 <= 1e-12 * a0.max(), f"{scene.name} --subdivide {bound}")
    for mat in np.unique(q0[f0[:, 0]]):
        a = _measures(v0, f0[q0[f0[:, 0]] == mat], uv0)
        sel = f1[q1[f1[:, 0]] == mat]
        b = _measures(v1, sel, uv1)
        where = f"{scene.name} --subdivide {bound}, material {int(mat)}"
        assert b["area"] == pytest.approx(a["area"], rel=1e-5), f"{where}: area {a['area']} -> {b['area']}"
        assert b["uv_area"] == pytest.approx(a["uv_area"], rel=1e-5, abs=1e-6), f"{where}: lightmap UV area {a['uv_area']} -> {b['uv_area']}"
        # Splitting an edge at a point where another surface's vertex already was closes a
        # T-junction (less boundary); no crack may open (more boundary).
        assert b["boundary"] <= a["boundary"] * (1 + 1e-5) + 1e-6, f"{where}: boundary length {a['boundary']} -> {b['boundary']} m"
        if bound == "lightmap":
            lm = uv1[np.unique(sel)]
            if np.any(lm != 0):  # a lightmapped material: edges measured in texels
                longest = _longest(np.c_[uv1, np.zeros(len(uv1))], sel)
                assert longest <= 1.0 + 1e-3, f"{where}: an edge spans {longest} texels"
        else:
            longest = _longest(v1, sel)
            assert longest <= float(bound) * (1 + 1e-5), f"{where}: an edge is {longest} m long"


@pytest.mark.parametrize("bound", ["lightmap", "0.5"])
def test_subdivision_of_the_sample(q3gltf, tmp_path, bound):
    scene = tmp_path / "sample.gltf"
    _run(str(q3gltf), "convert", str(REPO / "samples/sample/maps/sample.bsp"), "-q", "-o", str(scene))
    _check(q3gltf, scene, bound, tmp_path)


def test_subdivision_of_oa_dm1(q3gltf, baseoa, tmp_path):
    scene = tmp_path / "oa_dm1.glb"
    _run(str(q3gltf), "convert", "oa_dm1", "--game-dir", str(baseoa), "-q", "-o", str(scene))
    _check(q3gltf, scene, "lightmap", tmp_path)
