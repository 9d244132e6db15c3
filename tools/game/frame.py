"""The game's own frames: OpenArena on Debian's ioquake3, classic renderer, headless
under Xvfb, from given view poses. The reference a relit scene is judged against
(`make render`); a test and bench tool, never something the converter needs.

    python tools/game/frame.py --engine DIR --map oa_dm1 --out OUT \\
        (--gltf MAP.gltf --spawns 3 | --pose X Y Z YAW ...) [--width 640 --height 480]

`--engine` is the engine's `fs_basepath` that `samples/fetch-openarena.sh --engine`
prints; the engine binary is `ioquake3` (apt). Writes `OUT/game_K.png` (K = 0, 1, ...) and
`OUT/poses.json`: for each view the eye position in Quake units and the yaw in degrees
that the engine reports (`viewpos`) for the frame it drew.

How the frame is made, and why:
- Classic renderer (`cl_renderer opengl1`), `r_overBrightBits 0` and `r_ignorehwgamma 1`:
  the lightmaps' overbright shift is applied to the lightmap bytes (`r_mapOverBrightBits`
  2, the default), not to the screen's gamma ramp, so the shift is in the frame.
  `r_picmip 0`: full-size textures. No HUD, gun, crosshair or notify text.
- The camera is a spectator (no gravity, clips against the world). `setviewpos` puts the
  player at a position (eye = origin + 1 + view height 26) and then pushes it forward
  (400 units/s against the spectator's friction: about 75 units from a spawn point, the
  same every run within a unit). Asking for a point further back to make up for it would often start
  the spectator inside a wall, where it sticks; so the frame is taken where the push ends,
  after it has died out, and the pose used is always the one read back with `viewpos`.
- The horizontal field of view is `cg_fov` 90 degrees; at a 4:3 size the engine and a
  camera with a 90 degree horizontal angle agree.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image

ENGINE_BIN = "/usr/lib/ioquake3/ioquake3"
SPAWN_CLASSES = ("info_player_deathmatch", "info_player_start", "team_CTF_redspawn", "team_CTF_bluespawn")
#: Frames to wait after a teleport: the spectator's push has died out after about a second.
SETTLE_FRAMES = 150
VIEWPOS = re.compile(r"^\((-?\d+) (-?\d+) (-?\d+)\) : (-?\d+)\s*$")


def spawn_poses(gltf: Path, count: int) -> list[dict]:
    """The first `count` spawn points of a map converted by `q3gltf convert` (node extras
    `classname`, `origin`, `angle`; sorted by node name like tools/blender/render.py), as
    requested poses: the player's origin and yaw in degrees."""
    doc = json.loads(gltf.read_text()) if gltf.suffix == ".gltf" else _glb_json(gltf)
    spawns = []
    for node in doc.get("nodes", []):
        ex = node.get("extras") or {}
        if ex.get("classname") in SPAWN_CLASSES and "origin" in ex:
            x, y, z = (float(v) for v in str(ex["origin"]).split()[:3])
            spawns.append((node.get("name", ""), {"origin": [x, y, z], "yaw": float(ex.get("angle", 0) or 0)}))
    spawns.sort(key=lambda s: s[0])
    if not spawns:
        raise SystemExit(f"{gltf}: no spawn point (node extras with classname {'/'.join(SPAWN_CLASSES)})")
    return [dict(p, spawn=name) for name, p in spawns[:count]]


def _glb_json(path: Path) -> dict:
    data = path.read_bytes()
    n = int.from_bytes(data[12:16], "little")
    return json.loads(data[20:20 + n])


class Display:
    """An Xvfb server on a free display number, stopped on exit."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height

    def __enter__(self) -> str:
        for n in range(90, 190):
            if Path(f"/tmp/.X11-unix/X{n}").exists() or Path(f"/tmp/.X{n}-lock").exists():
                continue
            self.proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", f"{self.width}x{self.height}x24", "-nolisten", "tcp"],
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for _ in range(100):
                if Path(f"/tmp/.X11-unix/X{n}").exists():
                    self.name = f":{n}"
                    return self.name
                if self.proc.poll() is not None:
                    break
                time.sleep(0.05)
            self.proc.kill()
        raise SystemExit("Xvfb did not start (apt-get install xvfb)")

    def __exit__(self, *exc) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=10)


def _cvars(engine: Path, home: Path, width: int, height: int) -> list[str]:
    sets = {
        "com_basegame": "baseoa", "fs_basepath": str(engine), "fs_homepath": str(home),
        "com_legacyprotocol": "71", "com_protocol": "71", "com_introplayed": "1",
        "cl_renderer": "opengl1", "r_mode": "-1", "r_customwidth": str(width),
        "r_customheight": str(height), "r_fullscreen": "0", "r_overBrightBits": "0",
        "r_ignorehwgamma": "1", "r_picmip": "0", "r_gamma": "1", "r_intensity": "1",
        "r_mapOverBrightBits": "2", "r_vertexlight": "0", "r_dynamiclight": "0",
        "cg_drawgun": "0", "cg_draw2D": "0", "cg_drawCrosshair": "0", "cg_fov": "90",
        "con_notifytime": "0", "s_initsound": "0", "logfile": "2", "sv_pure": "0",
        "bot_enable": "0", "cl_motd": "0",
    }
    args = []
    for k, v in sets.items():
        args += ["+set", k, v]
    return args


def _run_engine(engine: Path, map_name: str, requests: list[dict], width: int, height: int,
                timeout_s: float) -> tuple[list[tuple[list[float], float]], list[Path], Path]:
    """One engine run: each requested pose (origin, yaw) shot once. Returns the poses read
    back, the screenshots (in order) and the scratch folder holding them."""
    if not Path(ENGINE_BIN).exists():
        raise SystemExit(f"{ENGINE_BIN} not found (apt-get install ioquake3)")
    home = Path(tempfile.mkdtemp(prefix="q3gltf-game-"))
    game = home / "baseoa"
    game.mkdir()
    # Frames to let the map load and the client enter before anything is asked of it.
    lines = ["wait 250", "team spectator", "wait 200"]
    for i, r in enumerate(requests):
        x, y, z = r["origin"]
        lines += [f"setviewpos {x:.3f} {y:.3f} {z:.3f} {r['yaw']:.3f}", f"wait {SETTLE_FRAMES}",
                  "viewpos", f"screenshot shot_{i:03d}", "wait 5"]
    lines += ["quit"]
    (game / "frames.cfg").write_text("\n".join(lines) + "\n")
    cmd = [ENGINE_BIN] + _cvars(engine, home, width, height) + ["+devmap", map_name, "+exec", "frames.cfg"]
    with Display(width, height) as display:
        env = dict(os.environ, DISPLAY=display)
        try:
            proc = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  timeout=timeout_s, text=True, errors="replace")
        except subprocess.TimeoutExpired:
            shutil.rmtree(home, ignore_errors=True)
            raise SystemExit(f"the engine did not finish {map_name} in {timeout_s:.0f} s")
    log = proc.stdout
    poses = []
    for line in log.splitlines():
        m = VIEWPOS.match(line.strip())
        if m:
            x, y, z, yaw = (float(v) for v in m.groups())
            poses.append(([x, y, z], yaw))
    shots = [game / "screenshots" / f"shot_{i:03d}.tga" for i in range(len(requests))]
    missing = [s.name for s in shots if not s.exists()]
    if proc.returncode != 0 or missing or len(poses) != len(requests):
        tail = "\n".join(log.splitlines()[-25:])
        shutil.rmtree(home, ignore_errors=True)
        raise SystemExit(f"the engine failed on {map_name} (exit {proc.returncode}, {len(poses)} of "
                         f"{len(requests)} poses read back, missing {missing}):\n{tail}")
    return poses, shots, home


def shoot(engine: Path, map_name: str, requests: list[dict], out: Path, width: int = 640,
          height: int = 480, timeout_s: float = 300.0) -> list[dict]:
    """The game's frames of `map_name` from the requested poses (player origin in Quake
    units, yaw in degrees), written to OUT/game_K.png with OUT/poses.json. Returns the
    poses as written: `eye` (units) and `yaw` (degrees) read back from the engine."""
    poses, shots, home = _run_engine(engine, map_name, requests, width, height, timeout_s)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for k, (r, (eye, yaw), shot) in enumerate(zip(requests, poses, shots)):
        img = Image.open(shot).convert("RGB")
        tmp = out / f".game_{k}.png.tmp"
        img.save(tmp, format="PNG")
        tmp.replace(out / f"game_{k}.png")
        written.append({"view": k, "map": map_name, "spawn": r.get("spawn"), "requested_origin": r["origin"],
                        "eye": eye, "yaw": yaw, "width": width, "height": height, "fov_x_deg": 90.0,
                        "image": f"game_{k}.png"})
    shutil.rmtree(home, ignore_errors=True)
    tmp = out / ".poses.json.tmp"
    tmp.write_text(json.dumps(written, indent=1) + "\n")
    tmp.replace(out / "poses.json")
    return written


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine", type=Path, required=True, help="fs_basepath from samples/fetch-openarena.sh --engine")
    ap.add_argument("--map", required=True, help="map name as the game knows it (oa_dm1, oacmpdm4)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--gltf", type=Path, help="the converted map, for its spawn points")
    ap.add_argument("--spawns", type=int, default=3, help="how many spawn points (with --gltf)")
    ap.add_argument("--pose", type=float, nargs=4, action="append", metavar=("X", "Y", "Z", "YAW"),
                    help="a player origin (Quake units) and yaw (degrees); repeatable")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    args = ap.parse_args(argv)
    if args.pose:
        requests = [{"origin": p[:3], "yaw": p[3]} for p in args.pose]
    elif args.gltf:
        requests = spawn_poses(args.gltf, args.spawns)
    else:
        ap.error("give --gltf (spawn points) or --pose")
    for p in shoot(args.engine, args.map, requests, args.out, args.width, args.height):
        print(f"{args.out / p['image']}: eye {p['eye']} yaw {p['yaw']}")


if __name__ == "__main__":
    main(sys.argv[1:])
