"""Opaque brush faces overlapping on one plane: convert cuts them, checked independently.

q3map2 keeps both faces where brushes overlap (detail brushes, trims over floors); the
game draws both alike, but Cycles shadows one with the other and renders the overlap
black (oa_dm1's floor by the pillar, issue 12). `q3gltf convert` cuts the later face
(convert/src/overlap.rs); `--keep-overlaps` keeps the BSP's triangles.

This checker is written apart from that code (numpy, Sutherland-Hodgman on each pair):
triangles of one mesh whose materials are opaque, grouped by plane (normal to 1e-3,
distance to 0.01 unit, the same facing), pairs whose bounding boxes meet, the area of
their intersection. On real maps it must find

* the overlaps in the `--keep-overlaps` output (so the check can fail), and none above
  0.5 square units in the default output;
* the area convert reports removed equal (within 2%) to the drop in the meshes' total
  area, and no more than the pairwise overlap area it measured in the kept output
  (pairs double count where three faces overlap; the union is what is removed).
"""
from __future__ import annotations

import json
import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from gltf_io import accessor, read_glb

MAPS = ("oa_dm1", "aggressor", "kaos")
UNITS_PER_M = 1.0 / 0.0254
MIN_PAIR = 0.5  # square Quake units


def opaque_triangles(path: Path) -> list[np.ndarray]:
    """Per mesh, its opaque triangles (n, 3, 3) in Quake units, glTF axes."""
    doc, binary = read_glb(path)
    out = []
    for mesh in doc["meshes"]:
        tris = []
        for prim in mesh["primitives"]:
            mat = doc["materials"][prim["material"]]
            if mat.get("alphaMode", "OPAQUE") != "OPAQUE":
                continue
            pos = accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64) * UNITS_PER_M
            idx = accessor(doc, binary, prim["indices"]).reshape(-1, 3)
            tris.append(pos[idx])
        if tris:
            out.append(np.concatenate(tris))
    return out


def clipped_area(a: np.ndarray, b: np.ndarray) -> float:
    """Area of triangle `a` clipped to triangle `b` (2D, any winding)."""
    def cross(u, v):
        return u[0] * v[1] - u[1] * v[0]
    s = np.sign(cross(b[1] - b[0], b[2] - b[0]))
    poly = list(a)
    for k in range(3):
        e0, e1 = b[k], b[(k + 1) % 3]
        new = []
        for j in range(len(poly)):
            p, q = poly[j], poly[(j + 1) % len(poly)]
            fp, fq = s * cross(e1 - e0, p - e0), s * cross(e1 - e0, q - e0)
            if fp >= 0:
                new.append(p)
            if (fp >= 0) != (fq >= 0):
                new.append(p + (q - p) * (fp / (fp - fq)))
        poly = new
        if len(poly) < 3:
            return 0.0
    xs, ys = np.array([p[0] for p in poly]), np.array([p[1] for p in poly])
    return 0.5 * abs(np.dot(xs, np.roll(ys, -1)) - np.dot(ys, np.roll(xs, -1)))


def overlaps(meshes: list[np.ndarray]) -> tuple[float, int, float]:
    """(pairwise overlap area, pairs above MIN_PAIR, total area), square Quake units."""
    pair_area, pairs, total = 0.0, 0, 0.0
    for t in meshes:
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        area = 0.5 * np.linalg.norm(n, axis=1)
        total += area.sum()
        ok = area > 1e-4
        unit = n[ok] / (2 * area[ok])[:, None]
        t = t[ok]
        dist = (unit * t[:, 0]).sum(1)
        groups = defaultdict(list)
        for i, (u, d) in enumerate(zip(np.round(unit, 3) + 0.0, np.round(dist, 2) + 0.0)):
            groups[(tuple(u), d)].append(i)
        for (u, _), ids in groups.items():
            if len(ids) < 2:
                continue
            axis = int(np.argmax(np.abs(u)))
            keep = [k for k in range(3) if k != axis]
            flat = t[ids][:, :, keep]
            lo, hi = flat.min(1), flat.max(1)
            for a in range(len(ids)):
                meet = np.all(lo[a + 1:] <= hi[a] + 0.01, axis=1) & np.all(hi[a + 1:] >= lo[a] - 0.01, axis=1)
                for b in np.nonzero(meet)[0] + a + 1:
                    x = clipped_area(flat[a], flat[b])
                    pair_area += x
                    pairs += x > MIN_PAIR
    return pair_area, pairs, total


@pytest.fixture(scope="module")
def converted(q3gltf, baseoa, tmp_path_factory):
    root = tmp_path_factory.mktemp("overlaps")
    out = {}
    for name in MAPS:
        for mode, extra in (("cut", []), ("keep", ["--keep-overlaps"])):
            path = root / f"{name}.{mode}.glb"
            res = subprocess.run([str(q3gltf), "convert", name, "--game-dir", str(baseoa), "-o", str(path), "--json"] + extra,
                                 capture_output=True, text=True, timeout=300)
            assert res.returncode == 0, res.stderr
            out[(name, mode)] = (path, json.loads(res.stdout))
    return out


@pytest.mark.parametrize("name", MAPS)
def test_no_opaque_faces_overlap_on_one_plane(name, converted):
    cut_path, summary = converted[(name, "cut")]
    keep_path, _ = converted[(name, "keep")]
    kept_pairs_area, kept_pairs, kept_total = overlaps(opaque_triangles(keep_path))
    cut_pairs_area, cut_pairs, cut_total = overlaps(opaque_triangles(cut_path))
    removed = summary["surfaces"]["overlaps"]["area_removed_m2"] * UNITS_PER_M ** 2
    print(f"{name}: kept {kept_pairs} overlapping pairs ({kept_pairs_area:.0f} sq units), "
          f"cut {cut_pairs} ({cut_pairs_area:.1f}); removed {removed:.0f}, total {kept_total:.0f} -> {cut_total:.0f}")
    assert cut_pairs == 0, f"{cut_pairs} opaque triangle pairs still overlap by more than {MIN_PAIR} sq units"
    assert abs((kept_total - cut_total) - removed) <= 0.02 * max(removed, 1.0) + 1.0
    assert removed <= kept_pairs_area * 1.001 + 1.0


def test_oa_dm1_has_the_overlap_that_rendered_black(converted):
    """The floor strip by oa_dm1's pillar (x 952..968, y 1160..1448, z 48 in Quake axes):
    two brush faces there in the BSP, one after the cut."""
    _, kept_pairs, _ = overlaps(opaque_triangles(converted[("oa_dm1", "keep")][0]))
    assert kept_pairs > 100
    for mode, want in (("keep", 2), ("cut", 1)):
        meshes = opaque_triangles(converted[("oa_dm1", mode)][0])
        # The point (960, 1340, 48) in Quake axes is (960, 48, -1340) in glTF's.
        p = np.array([960.0, 48.0, -1340.0])
        hits = 0
        for t in meshes:
            n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
            up = n[:, 1] > 0
            on = np.all(np.abs(t[:, :, 1] - 48.0) < 0.01, axis=1) & up
            for tri in t[on]:
                a, b, c = tri[:, [0, 2]]
                d = lambda u, v, w: (v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0])
                q = p[[0, 2]]
                s = [d(a, b, q), d(b, c, q), d(c, a, q)]
                hits += all(x >= 0 for x in s) or all(x <= 0 for x in s)
        assert hits == want, f"{mode}: {hits} floor faces under the pillar's strip"
