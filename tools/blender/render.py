"""Cycles renders of a converted map from a spawn point: relit (the file's point lights)
and lightmapped (the baked lightmaps as emission, see lightmap_preview.py).

With `--poses OUT/poses.json` (written by tools/game/frame.py: the game's own frames and
the eye position and yaw the engine used), renders every view that file lists at its size
and 90 degree horizontal field of view: `relit_K.png` (the relit file in Cycles, its
lights, emission and ambient), `relit-display_K.png` (the same through the compositor
of game_display.py: shown the way the game shows light), `engine_K.png` (the baked
lighting as the engine draws it, lightmap_preview.game_preview) and `lightmap_K.png`
(the linear preview albedo x e), and `unlit_K.png` (white where no lightmap sets the look: the sky, unlit surfaces). tools/game/compare.py sets them beside the game's frames.

    python tools/blender/render.py --relit out/render/oa_dm1.relit.gltf \
        --original out/render/oa_dm1.gltf --out out/render [--width 960 --height 540
        --samples 64 --spawn 0 --bounces 0 --small 480]

Runs with PyPI's bpy (the `.venv-blender` of `make render`), or inside Blender
(`blender -b -P tools/blender/render.py -- ARGS`). Writes OUT/relit.png and
OUT/lightmap.png, plus half-size copies in OUT/small/ when --small is given. The camera
stands at the spawn point (an `info_player_deathmatch` empty, sorted by name), at the
player's eye height (26 units), looking along its `angle` with the game's 90 degree
horizontal field of view. Both images use the 'Standard' view transform, so that a
radiance of 1 is white in both.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import bpy
from mathutils import Vector

sys.path.insert(0, str(Path(__file__).resolve().parent))
import game_display  # noqa: E402
import lightmap_preview  # noqa: E402

EYE_HEIGHT_UNITS = 26.0  # ioq3 DEFAULT_VIEWHEIGHT
DEFAULT_SCALE = 0.0254   # meters per Quake unit (convert's default)


def load(path: Path) -> None:
    """A fresh, empty scene with the glTF imported (Blender's default import options)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(path))


def spawn_points() -> list:
    return sorted((o for o in bpy.data.objects
                   if o.type == "EMPTY" and o.get("classname") == "info_player_deathmatch"),
                  key=lambda o: o.name)


def game_camera(name: str, location, yaw_rad: float):
    """The scene's camera as the game's: at `location` (m), level, looking along `yaw_rad`
    (counter-clockwise from +X in Quake axes, which are Blender's after glTF import), 90
    degrees horizontally (cg_fov)."""
    cam_data = bpy.data.cameras.new(name)
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = math.radians(90.0)
    cam_data.clip_start = 0.01
    cam_data.clip_end = 1.0e5  # a map spans kilometres; Blender's default 100 m would cut its far walls and sky
    cam = bpy.data.objects.new(name, cam_data)
    bpy.context.scene.collection.objects.link(cam)
    cam.location = location
    cam.rotation_euler = (math.radians(90.0), 0.0, yaw_rad - math.radians(90.0))
    bpy.context.scene.camera = cam
    return cam


def add_spawn_camera(index: int = 0, scale: float = DEFAULT_SCALE):
    """A camera at spawn point `index`, eye height, looking along its `angle` (degrees)."""
    spawns = spawn_points()
    if not spawns:
        raise SystemExit("no info_player_deathmatch empty in the scene (imported without extras?)")
    sp = spawns[index % len(spawns)]
    yaw = math.radians(float(sp.get("angle", "0") or 0))
    return game_camera("spawn", sp.matrix_world.translation + Vector((0.0, 0.0, EYE_HEIGHT_UNITS * scale)), yaw)


def add_pose_camera(eye_units, yaw_deg: float, scale: float):
    """A camera at an eye position in Quake units (times the map's scale), looking along
    `yaw_deg`: a pose the engine reported (tools/game/frame.py)."""
    return game_camera("pose", Vector(eye_units) * scale, math.radians(yaw_deg))


def map_scale() -> float:
    return float(bpy.context.scene.get("q3_scale", DEFAULT_SCALE))


def setup_cycles(width: int, height: int, samples: int, bounces: int) -> None:
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = bounces
    scene.cycles.diffuse_bounces = bounces
    scene.cycles.glossy_bounces = bounces
    scene.cycles.transparent_max_bounces = 8
    scene.cycles.light_sampling_threshold = 0.0
    scene.cycles.use_denoising = False
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    world = bpy.data.worlds.new("black")
    world.color = (0.0, 0.0, 0.0)
    if world.node_tree is not None:  # Blender 5 gives new worlds a node tree
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    scene.world = world


def denoise_if_available() -> None:
    scene = bpy.context.scene
    try:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
        scene.cycles.use_denoising = True
    except (TypeError, AttributeError):
        scene.cycles.use_denoising = False


def render_png(path: Path, small_width: int | None = None) -> None:
    scene = bpy.context.scene
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.filepath = str(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.render.render(write_still=True)
    if small_width:
        img = bpy.data.images.load(str(path))
        w, h = img.size
        img.scale(small_width, max(1, round(h * small_width / w)))
        small = path.parent / "small" / path.name
        small.parent.mkdir(parents=True, exist_ok=True)
        img.filepath_raw = str(small)
        img.file_format = "PNG"
        img.save()


def render_pair(relit: Path, original: Path, out: Path, width: int, height: int, samples: int,
                spawn: int = 0, bounces: int = 0, denoise: bool = True,
                small_width: int | None = None) -> tuple[Path, Path]:
    """Render OUT/relit.png (relit file, its point lights) and OUT/lightmap.png (original
    file, lightmaps as emission) from the same spawn point."""
    load(relit)
    lightmap_preview.relit_materials()
    add_spawn_camera(spawn)
    setup_cycles(width, height, samples, bounces)
    if denoise:
        denoise_if_available()
    relit_png = out / "relit.png"
    render_png(relit_png, small_width)

    load(original)
    for o in [o for o in bpy.data.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(o)
    lightmap_preview.lightmap_preview()
    add_spawn_camera(spawn)
    setup_cycles(width, height, samples, 0)  # emission seen directly: no bounces needed
    if denoise:
        denoise_if_available()
    lightmap_png = out / "lightmap.png"
    render_png(lightmap_png, small_width)
    return relit_png, lightmap_png


def render_views(relit: Path, original: Path, poses_json: Path, out: Path, samples: int,
                 bounces: int | None = None, denoise: bool = True,
                 also: list[tuple[str, Path]] | None = None, only: set[str] | None = None) -> list[Path]:
    """Render every view of `poses_json` three ways (see the module docs), and each
    further relit file of `also` as NAME_K.png. Returns the files."""
    import json
    poses = json.loads(poses_json.read_text())
    written = []

    def wanted(prefix: str) -> bool:
        return only is None or prefix in only

    def each_view(prefix: str, samples_: int, bounces_: int) -> None:
        for p in poses:
            for o in [o for o in bpy.data.objects if o.type == "CAMERA"]:
                bpy.data.objects.remove(o)
            add_pose_camera(p["eye"], p["yaw"], map_scale())
            setup_cycles(p["width"], p["height"], samples_, bounces_)
            if denoise:
                denoise_if_available()
            path = out / f"{prefix}_{p['view']}.png"
            render_png(path)
            written.append(path)

    for prefix, path, display in [("relit", relit, False), ("relit-display", relit, True)] + [(n, p, False) for n, p in also or []]:
        if not wanted(prefix):
            continue
        load(path)
        lightmap_preview.relit_materials()
        if display:
            game_display.setup()
        relit_info = bpy.context.scene.get("q3_relight")
        n = bounces
        if n is None:  # as many bounces as the fit modelled (none when it folded them into the lights)
            n = int(relit_info.get("bounces", 0)) if relit_info is not None and relit_info.get("bounce_scale") is not None else 0
        each_view(prefix, samples, n)
    for prefix, rewire in (("engine", lightmap_preview.game_preview), ("lightmap", lightmap_preview.lightmap_preview)):
        if not wanted(prefix):
            continue
        load(original)
        for o in [o for o in bpy.data.objects if o.type == "LIGHT"]:
            bpy.data.objects.remove(o)
        rewire()
        each_view(prefix, max(4, samples // 4), 0)  # emission seen directly: only anti-aliasing
    # Where no lightmap sets the look (the sky, unlit surfaces): white, everything else black.
    # The game draws its own sky and shader effects there (sky boxes, scrolling clouds,
    # stars, animated stages) that no glTF material carries.
    if wanted("unlit"):
        load(original)
        for o in [o for o in bpy.data.objects if o.type == "LIGHT"]:
            bpy.data.objects.remove(o)
        mask_materials()
        each_view("unlit", 4, 0)
    return written


def mask_materials() -> None:
    """Every surface under convert's "sky" node or with an unlit material (no lightmap, no
    vertex lighting) emits white, every other one black."""
    def emitter(name, value):
        m = bpy.data.materials.new(name)
        nodes = m.node_tree.nodes
        nodes.clear()
        emit = nodes.new("ShaderNodeEmission")
        emit.inputs["Color"].default_value = (value, value, value, 1.0)
        out = nodes.new("ShaderNodeOutputMaterial")
        m.node_tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
        return m
    white, black = emitter("unlit mask", 1.0), emitter("lit", 0.0)
    for o in bpy.data.objects:
        if o.type != "MESH":
            continue
        sky = lightmap_preview.is_sky_object(o)
        if not o.material_slots:
            o.data.materials.append(white if sky else black)
        for slot in o.material_slots:
            unlit = sky or slot.material is None or lightmap_preview.lighting_kind(slot.material) == "none"
            slot.link = "OBJECT"
            slot.material = white if unlit else black


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--relit", type=Path, required=True)
    ap.add_argument("--original", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--spawn", type=int, default=0, help="which info_player_deathmatch (sorted by name)")
    ap.add_argument("--bounces", type=int, default=None,
                    help="Cycles bounces for the relit image (default: 0, or with --poses the passes "
                         "of bounced light the relit file says its fit modelled)")
    ap.add_argument("--no-denoise", action="store_true")
    ap.add_argument("--small", type=int, default=None, help="also write OUT/small/*.png this wide")
    ap.add_argument("--also", action="append", default=[], metavar="NAME=PATH",
                    help="with --poses: another relit file, rendered as OUT/NAME_K.png (repeatable)")
    ap.add_argument("--only", default=None, metavar="KIND,...",
                    help="with --poses: render only these (relit, relit-display, NAME of --also, engine, lightmap, unlit)")
    ap.add_argument("--poses", type=Path, default=None,
                    help="poses.json of tools/game/frame.py: render its views (relit, engine, lightmap) instead")
    args = ap.parse_args(argv)
    if args.poses is not None:
        for p in render_views(args.relit, args.original, args.poses, args.out, args.samples,
                              args.bounces, not args.no_denoise,
                              [(a.split("=", 1)[0], Path(a.split("=", 1)[1])) for a in args.also],
                              set(args.only.split(",")) if args.only else None):
            print(p)
        return
    for p in render_pair(args.relit, args.original, args.out, args.width, args.height, args.samples,
                         args.spawn, args.bounces or 0, not args.no_denoise, args.small):
        print(p)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
