"""Cycles renders of a converted map from a spawn point: relit (the file's point lights)
and lightmapped (the baked lightmaps as emission, see lightmap_preview.py).

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


def add_spawn_camera(index: int = 0, scale: float = DEFAULT_SCALE):
    """A camera at spawn point `index`, eye height, looking along its `angle` (degrees,
    counter-clockwise from +X in Quake axes, which are Blender's after glTF import)."""
    spawns = spawn_points()
    if not spawns:
        raise SystemExit("no info_player_deathmatch empty in the scene (imported without extras?)")
    sp = spawns[index % len(spawns)]
    yaw = math.radians(float(sp.get("angle", "0") or 0))
    cam_data = bpy.data.cameras.new("spawn")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = math.radians(90.0)
    cam_data.clip_start = 0.01
    cam = bpy.data.objects.new("spawn", cam_data)
    bpy.context.scene.collection.objects.link(cam)
    cam.location = sp.matrix_world.translation + Vector((0.0, 0.0, EYE_HEIGHT_UNITS * scale))
    cam.rotation_euler = (math.radians(90.0), 0.0, yaw - math.radians(90.0))
    bpy.context.scene.camera = cam
    return cam


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


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--relit", type=Path, required=True)
    ap.add_argument("--original", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--spawn", type=int, default=0, help="which info_player_deathmatch (sorted by name)")
    ap.add_argument("--bounces", type=int, default=0,
                    help="Cycles bounces for the relit image (0: direct light only, as the lightmap)")
    ap.add_argument("--no-denoise", action="store_true")
    ap.add_argument("--small", type=int, default=None, help="also write OUT/small/*.png this wide")
    args = ap.parse_args(argv)
    for p in render_pair(args.relit, args.original, args.out, args.width, args.height, args.samples,
                         args.spawn, args.bounces, not args.no_denoise, args.small):
        print(p)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
