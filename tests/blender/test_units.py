"""Light units, end to end: one light as Blender exported it (test_roundtrip's edit), above a
white Lambertian plane, rendered by Cycles (CPU, 16 samples, 64x64, EXR) and compared with
relight's own forward model at the same point (`q3gltf probe`): within 5%.

The plane scene is a glTF written here (plane + that KHR light); Blender imports it with its
default options (cd -> W = cd * 4 pi / 683), its material becomes a white Diffuse BSDF, and
an orthographic camera looks straight down at a 5 cm square under the light."""
from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np

from helpers import import_gltf, light_nodes, read_gltf_json, run

HEIGHT = 1.5        # meters of the light above the plane
HALF = 2.0          # half size of the plane, meters
VIEW = 0.05         # width of the rendered square, meters


def write_plane_scene(path: Path, intensity_cd: float, color) -> None:
    """A 4 m x 4 m plane at y = 0 facing +Y (white, rough) and one point light above it."""
    pos = np.array([[-HALF, 0, -HALF], [-HALF, 0, HALF], [HALF, 0, HALF], [HALF, 0, -HALF]], "<f4")
    nrm = np.tile(np.array([0, 1, 0], "<f4"), (4, 1))
    idx = np.array([0, 1, 2, 0, 2, 3], "<u2")  # counter-clockwise seen from +Y
    blob = pos.tobytes() + nrm.tobytes() + idx.tobytes()
    path.with_suffix(".bin").write_bytes(blob)
    doc = {
        "asset": {"version": "2.0", "generator": "q3gltf tests/blender/test_units.py"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "point", "name": "probe_light", "intensity": intensity_cd, "color": list(color)}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "plane", "mesh": 0},
                  {"name": "probe_light", "translation": [0, HEIGHT, 0],
                   "extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "meshes": [{"name": "plane", "primitives": [
            {"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"name": "white", "pbrMetallicRoughness": {
            "baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0, "roughnessFactor": 1}}],
        "buffers": [{"uri": path.with_suffix(".bin").name, "byteLength": len(blob)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48, "target": 34962},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 48, "target": 34962},
                        {"buffer": 0, "byteOffset": 96, "byteLength": 12, "target": 34963}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [-HALF, 0, -HALF], "max": [HALF, 0, HALF]},
                      {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    path.write_text(json.dumps(doc, indent=1))


def cycles_radiance(bpy, scene_path: Path, exr: Path) -> np.ndarray:
    """Mean RGB radiance (W m^-2 sr^-1 per unit of light colour) that Cycles renders of the
    plane just under the light."""
    import_gltf(bpy, scene_path)
    scene = bpy.context.scene
    plane = bpy.data.objects["plane"]
    mat = bpy.data.materials.new("white_lambert")
    nodes = mat.node_tree.nodes
    nodes.clear()
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1, 1, 1, 1)
    diffuse.inputs["Roughness"].default_value = 0.0  # Lambertian
    out = nodes.new("ShaderNodeOutputMaterial")
    mat.node_tree.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    plane.data.materials.clear()
    plane.data.materials.append(mat)

    cam_data = bpy.data.cameras.new("down")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = VIEW
    cam = bpy.data.objects.new("down", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (0.0, 0.0, HEIGHT / 2)  # Blender Z up; looks along -Z by default
    scene.camera = cam

    world = bpy.data.worlds.new("black")
    world.color = (0, 0, 0)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.light_sampling_threshold = 0.0
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(exr)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(exr))
    px = np.array(img.pixels[:], dtype=np.float64).reshape(-1, 4)
    return px[:, :3].mean(axis=0)


def test_cycles_radiance_matches_probe(bpy, edited, q3gltf, workdir):
    # The moved light, as Blender exported it (intensity in cd and colour).
    exported = read_gltf_json(edited["paths"]["lights"])
    _, light = light_nodes(exported)[edited["moved"]]
    cd, color = light["intensity"], light.get("color", [1, 1, 1])
    assert cd > 1.0

    scene_path = workdir / "units_plane.gltf"
    write_plane_scene(scene_path, cd, color)
    probe = json.loads(run(q3gltf, "probe", scene_path, "--at", "0,0,0", "--normal", "0,1,0").stdout)
    expected = np.array(probe["radiance_white"])
    # The photometric definition, for the record: E = (cd / 683) / d^2 W/m2, L = E / pi.
    analytic = cd / 683 / HEIGHT**2 / math.pi * np.array(color)
    rendered = cycles_radiance(bpy, scene_path, workdir / "units_plane.exr")

    ratio = rendered / expected
    print(f"\ncd {cd:.1f}, colour {color}: Cycles {rendered}, probe {expected}, "
          f"analytic {analytic}, Cycles/probe {ratio}")
    assert np.allclose(expected, analytic, rtol=0.01)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio
