"""Light units, end to end, for every kind of emitter relight writes: a light above a white
Lambertian plane, rendered by Cycles (CPU, 64x64, EXR) and compared with relight's own
forward model at the same point (`q3gltf probe`): within 5%.

- a point light as Blender exported it (test_roundtrip's edit);
- a spot light pointing down (the point under it inside the inner cone);
- a sun (KHR directional light in lux) 30 degrees off the plane's normal;
- a sky light (the sky's emission, under convert's "sky" node, as relight writes it),
  rendered through the tooling's relit_materials (sky seen by the camera as its texture,
  sky surfaces casting no shadow), which must not change the light it gives;
- an emissive square (`emissiveFactor` x `KHR_materials_emissive_strength`, radiance in
  W/(m^2 sr)), as relight writes surface lights.

Each scene is a glTF written here; Blender imports it with its default options (cd -> W =
cd * 4 pi / 683), the plane's material becomes a white Diffuse BSDF, and an orthographic
camera looks straight down at a 5 cm square under the light."""
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


def write_plane_scene(path: Path, intensity_cd: float, color, kind: str = "point", emitter=None,
                      rotation=None, sky=None) -> None:
    """A 4 m x 4 m plane at y = 0 facing +Y (white, rough) and one emitter above it: a point
    or spot light (pointing down, inner/outer cone 0.3/0.5 rad) of `intensity_cd` and
    `color` at HEIGHT, or with `emitter = (half_size_m, height_m, strength)` a square facing
    down whose radiance is `color x strength` W/(m^2 sr) (and no light)."""
    pos = [[-HALF, 0, -HALF], [-HALF, 0, HALF], [HALF, 0, HALF], [HALF, 0, -HALF]]
    nrm = [[0, 1, 0]] * 4
    if emitter:
        h, y, _ = emitter
        # Counter-clockwise seen from below (-Y): its front faces the plane.
        pos += [[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]]
        nrm += [[0, -1, 0]] * 4
    pos = np.array(pos, "<f4")
    nrm = np.array(nrm, "<f4")
    idx = np.array([0, 1, 2, 0, 2, 3], "<u2")  # counter-clockwise seen from +Y
    blob = pos[:4].tobytes() + nrm[:4].tobytes() + idx.tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": 48, "target": 34962},
             {"buffer": 0, "byteOffset": 48, "byteLength": 48, "target": 34962},
             {"buffer": 0, "byteOffset": 96, "byteLength": 12, "target": 34963}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                  "min": [-HALF, 0, -HALF], "max": [HALF, 0, HALF]},
                 {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
                 {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]
    meshes = [{"name": "plane", "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}]
    materials = [{"name": "white", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0, "roughnessFactor": 1}}]
    nodes = [{"name": "plane", "mesh": 0}]
    doc = {"asset": {"version": "2.0", "generator": "q3gltf tests/blender/test_units.py"}, "scene": 0}
    if emitter:
        h, y, strength = emitter
        off = len(blob)
        blob += pos[4:].tobytes() + nrm[4:].tobytes() + idx.tobytes()
        views += [{"buffer": 0, "byteOffset": off, "byteLength": 48, "target": 34962},
                  {"buffer": 0, "byteOffset": off + 48, "byteLength": 48, "target": 34962},
                  {"buffer": 0, "byteOffset": off + 96, "byteLength": 12, "target": 34963}]
        accessors += [{"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-h, y, -h], "max": [h, y, h]},
                      {"bufferView": 4, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 5, "componentType": 5123, "count": 6, "type": "SCALAR"}]
        meshes.append({"name": "emitter", "primitives": [{"attributes": {"POSITION": 3, "NORMAL": 4}, "indices": 5, "material": 1}]})
        materials.append({"name": "glow", "emissiveFactor": list(color),
                          "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": strength}},
                          "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0, "roughnessFactor": 1}})
        nodes.append({"name": "emitter", "mesh": 1})
        doc["extensionsUsed"] = ["KHR_materials_emissive_strength"]
    elif sky:
        # Convert's "sky" node: a box of half size `h` and height `y` around the plane, open
        # at the bottom, its faces turned inwards, emitting `color x strength` (as relight
        # writes a sky light), with the shader's q3map_skyLight in the extras.
        h, y, strength = sky
        corners = [[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]]
        top = [[x, y, z] for x, _, z in corners]
        quads = [top[::-1]] + [[corners[i], corners[(i + 1) % 4], top[(i + 1) % 4], top[i]] for i in range(4)]
        spos = np.array([v for q in quads for v in q], "<f4")
        centre = np.array([0, y / 2, 0], "<f4")
        snrm = []
        for q in quads:
            qa = np.array(q, "<f4")
            n = np.cross(qa[1] - qa[0], qa[2] - qa[0])
            n /= np.linalg.norm(n)
            if np.dot(centre - qa.mean(axis=0), n) < 0:  # inwards
                n = -n
            snrm += [n] * 4
        snrm = np.array(snrm, "<f4")
        sidx = []
        for k, q in enumerate(quads):
            qa = np.array(q, "<f4")
            a, b, c = 4 * k, 4 * k + 1, 4 * k + 2
            face = np.cross(qa[1] - qa[0], qa[2] - qa[0])
            if np.dot(face, snrm[4 * k]) > 0:
                sidx += [a, b, c, a, c, 4 * k + 3]
            else:
                sidx += [a, c, b, a, 4 * k + 3, c]
        sidx = np.array(sidx, "<u2")
        off = len(blob)
        blob += spos.tobytes() + snrm.tobytes() + sidx.tobytes()
        views += [{"buffer": 0, "byteOffset": off, "byteLength": spos.nbytes, "target": 34962},
                  {"buffer": 0, "byteOffset": off + spos.nbytes, "byteLength": snrm.nbytes, "target": 34962},
                  {"buffer": 0, "byteOffset": off + spos.nbytes + snrm.nbytes, "byteLength": sidx.nbytes, "target": 34963}]
        accessors += [{"bufferView": 3, "componentType": 5126, "count": len(spos), "type": "VEC3",
                       "min": spos.min(axis=0).tolist(), "max": spos.max(axis=0).tolist()},
                      {"bufferView": 4, "componentType": 5126, "count": len(snrm), "type": "VEC3"},
                      {"bufferView": 5, "componentType": 5123, "count": len(sidx), "type": "SCALAR"}]
        meshes.append({"name": "sky", "primitives": [{"attributes": {"POSITION": 3, "NORMAL": 4}, "indices": 5, "material": 1}]})
        materials.append({"name": "textures/skies/test#unlit", "emissiveFactor": list(color),
                          "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": strength}},
                          "extras": {"q3_lighting": "none", "q3_skylight": [{"value": 100.0, "iterations": 8, "color": [1, 1, 1]}]},
                          "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0, "roughnessFactor": 1}})
        nodes.append({"name": "sky", "mesh": 1})
        doc["extensionsUsed"] = ["KHR_materials_emissive_strength"]
    else:
        light = {"type": kind, "name": "probe_light", "intensity": intensity_cd, "color": list(color)}
        node = {"name": "probe_light", "translation": [0, HEIGHT, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}}
        if kind == "spot":
            light["spot"] = {"innerConeAngle": 0.3, "outerConeAngle": 0.5}
            # -Z (where a glTF light shines) turned to -Y: -90 degrees about X.
            node["rotation"] = [-math.sqrt(0.5), 0, 0, math.sqrt(0.5)]
        if rotation is not None:
            node["rotation"] = list(rotation)
        doc["extensionsUsed"] = ["KHR_lights_punctual"]
        doc["extensions"] = {"KHR_lights_punctual": {"lights": [light]}}
        nodes.append(node)
    path.with_suffix(".bin").write_bytes(blob)
    doc.update({
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "buffers": [{"uri": path.with_suffix(".bin").name, "byteLength": len(blob)}],
        "bufferViews": views, "accessors": accessors,
    })
    path.write_text(json.dumps(doc, indent=1))


def cycles_radiance(bpy, scene_path: Path, exr: Path, samples: int = 16, prepare=None) -> np.ndarray:
    """Mean RGB radiance (W m^-2 sr^-1 per unit of light colour) that Cycles renders of the
    plane just under the light. `prepare()` runs after the import (the render tooling)."""
    import_gltf(bpy, scene_path)
    if prepare is not None:
        prepare()
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
    # A new world has a node tree whose Background is grey (0.05): black it too, or it adds
    # 0.05 W/(m^2 sr) to every pixel.
    if world.node_tree is not None:
        for node in world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0, 0, 0, 1)
                node.inputs["Strength"].default_value = 0.0
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
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


def probe_and_render(bpy, q3gltf, workdir: Path, name: str, color, samples: int = 16, prepare=None, **scene) -> tuple:
    scene_path = workdir / f"units_{name}.gltf"
    write_plane_scene(scene_path, color=color, **scene)
    probe = json.loads(run(q3gltf, "probe", scene_path, "--at", "0,0,0", "--normal", "0,1,0").stdout)
    rendered = cycles_radiance(bpy, scene_path, workdir / f"units_{name}.exr", samples, prepare)
    return probe, rendered


def test_cycles_radiance_of_a_spot_matches_probe(bpy, q3gltf, workdir):
    cd, color = 500.0, [1.0, 0.7, 0.4]
    probe, rendered = probe_and_render(bpy, q3gltf, workdir, "spot", color, intensity_cd=cd, kind="spot")
    expected = np.array(probe["radiance_white"])
    analytic = cd / 683 / HEIGHT**2 / math.pi * np.array(color)
    ratio = rendered / expected
    print(f"\nspot {cd} cd: Cycles {rendered}, probe {expected}, Cycles/probe {ratio}")
    # Wired as a spot: Blender's cone is the outer angle (its size the full angle).
    lights = [o for o in bpy.data.objects if o.type == "LIGHT"]
    assert len(lights) == 1 and lights[0].data.type == "SPOT", [(o.name, o.data.type) for o in lights]
    assert abs(lights[0].data.spot_size - 2 * 0.5) < 1e-3, lights[0].data.spot_size
    assert 0.0 < lights[0].data.spot_blend < 1.0
    assert probe["lights"] == 1 and probe["lights_visible"] == 1
    assert np.allclose(expected, analytic, rtol=0.01)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio


def test_cycles_radiance_of_an_emissive_surface_matches_probe(bpy, q3gltf, workdir):
    # A 1 m x 1 m square 1 m above the point, radiance (1, 0.8, 0.6) x 5 W/(m^2 sr).
    color, half, height, strength = [1.0, 0.8, 0.6], 0.5, 1.0, 5.0
    probe, rendered = probe_and_render(bpy, q3gltf, workdir, "emissive", color, samples=256,
                                       intensity_cd=0.0, emitter=(half, height, strength))
    expected = np.array(probe["radiance_white"])
    # The form factor of a square of side 2a at distance d centred above the point: four
    # a x a rectangles with a corner above it, each (1 / pi) x atan(x), x = a / sqrt(a^2 + d^2)
    # (the parallel-rectangle corner formula with both sides a).
    a, d = half, height
    x = a / math.sqrt(a * a + d * d)
    ff = 4 / math.pi * x * math.atan(x)
    analytic = strength * np.array(color) * ff  # E / pi = L F
    ratio = rendered / expected
    print(f"\nemissive {strength} W/(m2 sr): Cycles {rendered}, probe {expected}, analytic {analytic}, Cycles/probe {ratio}")
    assert probe["emissive_triangles"] == 2
    # Wired as emission: the imported material's emission colour and strength.
    bsdf = next(n for n in bpy.data.materials["glow"].node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    assert abs(bsdf.inputs["Emission Strength"].default_value - strength) < 1e-4
    assert np.allclose(list(bsdf.inputs["Emission Color"].default_value)[:3], color, atol=1e-4)
    assert np.allclose(expected, analytic, rtol=0.01), (expected, analytic)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio


def test_cycles_radiance_of_a_sun_matches_probe(bpy, q3gltf, workdir):
    # A directional light of 20000 lux, 30 degrees from straight down: -Z turned -60 degrees
    # about X shines along (0, -cos 30, -sin 30).
    lux, color, tilt = 20000.0, [1.0, 0.9, 0.7], math.radians(30.0)
    a = -(math.pi / 2 - tilt)
    probe, rendered = probe_and_render(bpy, q3gltf, workdir, "sun", color, intensity_cd=lux, kind="directional",
                                       rotation=[math.sin(a / 2), 0, 0, math.cos(a / 2)])
    expected = np.array(probe["radiance_white"])
    analytic = lux / 683 * math.cos(tilt) / math.pi * np.array(color)  # E = S cos(theta), L = E / pi
    ratio = rendered / expected
    print(f"\nsun {lux} lux: Cycles {rendered}, probe {expected}, analytic {analytic}, Cycles/probe {ratio}")
    suns = [o for o in bpy.data.objects if o.type == "LIGHT"]
    assert len(suns) == 1 and suns[0].data.type == "SUN", [(o.name, o.data.type) for o in suns]
    assert abs(suns[0].data.energy - lux / 683) < 1e-3 * lux / 683, suns[0].data.energy
    assert probe["suns"] == 1
    assert np.allclose(expected, analytic, rtol=0.01), (expected, analytic)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio


def test_cycles_radiance_of_a_sky_light_matches_probe(bpy, q3gltf, workdir):
    # A sky box 40 m across and 20 m high around the plane, radiance (0.6, 0.8, 1) x 2
    # W/(m^2 sr): an open plane under it receives E = pi L (a uniform radiance over the
    # whole hemisphere), which is what relight's sky model gives for the same emission.
    import lightmap_preview

    color, strength = [0.6, 0.8, 1.0], 2.0
    probe, rendered = probe_and_render(bpy, q3gltf, workdir, "sky", color, samples=256, intensity_cd=0.0,
                                       sky=(20.0, 20.0, strength), prepare=lightmap_preview.relit_materials)
    expected = np.array(probe["radiance_white"])
    # E / pi = L over the part of the hemisphere the box covers (all but the sides' last
    # few degrees down to the horizon: within 1%).
    analytic = strength * np.array(color)
    ratio = rendered / expected
    print(f"\nsky {strength} W/(m2 sr): Cycles {rendered}, probe {expected}, analytic {analytic}, Cycles/probe {ratio}")
    hidden = [o for o in bpy.data.objects if o.get("q3_sky_look") and not o.get("q3_sky_copy")]
    assert hidden and not hidden[0].visible_camera, "the sky's own surfaces hidden from the camera"
    assert np.allclose(expected, analytic, rtol=0.03), (expected, analytic)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio
