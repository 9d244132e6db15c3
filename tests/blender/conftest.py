"""Fixtures of the Blender round-trip tests (tests/blender), run with the real Blender as a
Python module (PyPI bpy==5.0.1, in `.venv-blender`: `make test-blender`).

Shares the data fixtures of tests/python/conftest.py (q3gltf binary, OpenArena data, the
Khronos validator). A missing bpy, binary, data or validator is a failure, never a skip.
"""
from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

from helpers import MOVE_BY, RELIGHT_FAST, VARIANTS, blender_to_gltf, import_gltf, run

REPO_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO_ROOT / "tools" / "blender"))

_spec = importlib.util.spec_from_file_location("q3gltf_harness", REPO_ROOT / "tests" / "python" / "conftest.py")
_harness = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = _harness
_spec.loader.exec_module(_harness)
q3gltf = _harness.q3gltf
baseoa = _harness.baseoa
node_validator = _harness.node_validator


@pytest.fixture(scope="session")
def bpy():
    try:
        import bpy as module
    except ImportError as exc:  # CI must run these tests: fail loudly
        pytest.fail(f"cannot import bpy (make blender-deps installs bpy==5.0.1 into .venv-blender): {exc}",
                    pytrace=False)
    return module


@pytest.fixture(scope="session")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blender")


@pytest.fixture(scope="session")
def dm1(q3gltf, baseoa, workdir) -> Path:
    """oa_dm1 converted to .gltf (+ .bin, textures)."""
    out = workdir / "oa_dm1.gltf"
    run(q3gltf, "convert", "oa_dm1", "--game-dir", baseoa, "-q", "-o", out)
    return out


@pytest.fixture(scope="session")
def dm1_relit(q3gltf, dm1, workdir) -> Path:
    """oa_dm1 relit with a small budget (3x3 grid start, a few seconds on the CPU)."""
    out = workdir / "oa_dm1.relit.gltf"
    run(q3gltf, "relight", dm1, "-o", out, "--init", "grid:3", "--report", workdir / "oa_dm1.report.json",
        *RELIGHT_FAST)
    return out


@pytest.fixture(scope="session")
def edited(bpy, dm1_relit, workdir):
    """Import, edit, export both variants. Returns what was done and the two paths."""
    import bmesh
    from mathutils import Vector

    import_gltf(bpy, dm1_relit)
    objs = bpy.data.objects
    lights = sorted((o for o in objs if o.type == "LIGHT"), key=lambda o: -o.data.energy)
    moved, locked, deleted = lights[0], lights[1], lights[2]
    moved.location = moved.location + Vector(MOVE_BY)
    locked["locked"] = True
    done = {
        "moved": moved.name, "moved_to": blender_to_gltf(moved.location),
        "locked": locked.name, "locked_at": blender_to_gltf(locked.location),
        "locked_cd": locked.data.energy * 683 / (4 * math.pi),
        "deleted": deleted.name,
    }
    objs.remove(deleted)

    # Geometry: a whole brush model, and every face of one world material.
    door = objs["*2 func_door"]
    removed = len(door.data.polygons)
    objs.remove(door)
    world = objs["world"]
    slot = next(i for i, s in enumerate(world.material_slots) if s.material.name == "textures/base_trim/pewter")
    bm = bmesh.new()
    bm.from_mesh(world.data)
    faces = [f for f in bm.faces if f.material_index == slot]
    removed += len(faces)
    bmesh.ops.delete(bm, geom=faces, context="FACES")
    bm.to_mesh(world.data)
    bm.free()
    done["removed_triangles"] = removed
    assert removed > 10

    # A new object without lightmap in the middle of a room: at a spawn point, 0.5 m up.
    spawn = sorted((o for o in objs if o.get("classname") == "info_player_deathmatch"), key=lambda o: o.name)[0]
    bpy.ops.mesh.primitive_cube_add(size=0.4, location=spawn.location + Vector((0, 0, 0.5)))
    done["cube"] = bpy.context.active_object.name

    done["paths"] = {}
    for variant, extra in VARIANTS.items():
        path = workdir / f"edited.{variant}.glb"
        bpy.ops.export_scene.gltf(filepath=str(path), **{"export_lights": True, **extra})
        done["paths"][variant] = path
    return done
