"""Set Blender's renders beside the game's own frames and measure how far each is.

    python tools/game/compare.py --table OUT/render/table --views DIR [DIR ...] \\
        [--side-by-side OUT/render/side_by_side]

Each DIR holds one map's `poses.json` and `game_K.png` (tools/game/frame.py) and
`engine_K.png`, `relit_K.png`, `lightmap_K.png` (tools/blender/render.py --poses). For
every view: the relative error of each render against the game's frame in linear light,
`||render - game|| / ||game||` over all pixels and channels, both decoded from their
8-bit sRGB values with the sRGB transfer function (IEC 61966-2-1: what Blender's
'Standard' view transform encodes and what a screen shows), and each image's mean linear
colour. Writes TABLE.md and TABLE.csv, and one PNG per view with the images side by side
(game | engine preview | each relit render).

The engine preview is the floor: the baked lighting itself, drawn the way the engine
draws it; what it misses (texture filtering and mip levels, items, models, the sky, the
spectator's exact pose) no relighting can recover. The issue's goal is relit <= 1.5 x floor.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

KINDS = ("engine", "relit", "lightmap")
LABELS = {"engine": "engine preview (floor)", "relit": "relit (Cycles)", "lightmap": "albedo x e (linear preview)"}


def kinds_in(d: Path) -> list[str]:
    """engine, relit, lightmap, then any other NAME of NAME_K.png render.py wrote (--also)."""
    found = sorted({f.name.rsplit("_", 1)[0] for f in d.glob("*_[0-9]*.png")} - {"game", "unlit"})
    return [k for k in KINDS if k in found] + [k for k in found if k not in KINDS]


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse, for values in [0, 1]."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def load_linear(path: Path) -> np.ndarray:
    return srgb_to_linear(np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0)


def rel_error(render: np.ndarray, game: np.ndarray, keep: np.ndarray | None = None) -> float:
    """`||render - game|| / ||game||` over the pixels `keep` (all by default)."""
    if render.shape != game.shape:
        raise SystemExit(f"image sizes differ: {render.shape} against the game's {game.shape}")
    if keep is not None:
        render, game = render[keep], game[keep]
    den = float(np.sqrt(np.sum(game * game)))
    return float(np.sqrt(np.sum((render - game) ** 2))) / den if den > 0 else float("inf")


def compare_dir(d: Path) -> list[dict]:
    poses = json.loads((d / "poses.json").read_text())
    rows = []
    for p in poses:
        k = p["view"]
        game = load_linear(d / f"game_{k}.png")
        row = {"map": p["map"], "view": k, "spawn": p.get("spawn") or "", "eye": " ".join(f"{v:g}" for v in p["eye"]),
               "yaw": p["yaw"], "game_mean": game.reshape(-1, 3).mean(0).round(4).tolist()}
        unlit = d / f"unlit_{k}.png"
        keep = np.asarray(Image.open(unlit).convert("L")) < 128 if unlit.exists() else None
        if keep is not None:
            row["unlit_fraction"] = float(1.0 - keep.mean())
        for kind in kinds_in(d):
            f = d / f"{kind}_{k}.png"
            if f.exists():
                img = load_linear(f)
                row[kind] = rel_error(img, game)
                if keep is not None:
                    row[f"{kind}_lit"] = rel_error(img, game, keep)
                row[f"{kind}_mean"] = img.reshape(-1, 3).mean(0).round(4).tolist()
        for kind in kinds_in(d):
            if kind.startswith("relit") and kind in row and row.get("engine", 0) > 0:
                row[f"{kind}_over_floor"] = row[kind] / row["engine"]
            if kind.startswith("relit") and f"{kind}_lit" in row and row.get("engine_lit", 0) > 0:
                row[f"{kind}_lit_over_floor"] = row[f"{kind}_lit"] / row["engine_lit"]
        rows.append(row)
    return rows


def side_by_side(d: Path, view: int, out: Path, kinds: list[str], scale: float = 1.0) -> None:
    names = ["game"] + [k for k in kinds if (d / f"{k}_{view}.png").exists()]
    ims = [Image.open(d / f"{n}_{view}.png").convert("RGB") for n in names]
    w, h = (max(1, round(v * scale)) for v in ims[0].size)
    sheet = Image.new("RGB", (w * len(ims) + 4 * (len(ims) - 1), h), (255, 255, 255))
    for i, im in enumerate(ims):
        sheet.paste(im.resize((w, h), Image.Resampling.LANCZOS), (i * (w + 4), 0))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    sheet.save(tmp, format="PNG")
    tmp.replace(out)


def write_table(rows: list[dict], stem: Path) -> str:
    stem.parent.mkdir(parents=True, exist_ok=True)
    kinds = []
    for r in rows:
        kinds += [k for k in r if k not in kinds and f"{k}_mean" in r]
    relits = [k for k in kinds if k.startswith("relit")]
    cols = (["map", "view", "spawn", "eye", "yaw", "unlit_fraction"] + kinds + [f"{k}_over_floor" for k in relits]
            + [f"{k}_lit" for k in kinds] + [f"{k}_lit_over_floor" for k in relits] + ["game_mean"] + [f"{k}_mean" for k in kinds])
    with open(stem.with_suffix(".csv.tmp"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()})
    stem.with_suffix(".csv.tmp").replace(stem.with_suffix(".csv"))
    fmt = lambda v: f"{v:.3f}" if isinstance(v, float) else "-"
    label = lambda k: LABELS.get(k, k)
    head = [label(k) for k in kinds] + [f"{k} / floor" for k in relits]
    lines = ["Relative error against the game's own frame (linear light; 0 = the same picture).", "",
             "| map | view (eye, yaw) | " + " | ".join(head) + " |", "|---|---|" + "---:|" * len(head)]
    for r in rows:
        vals = [fmt(r.get(k)) for k in kinds] + [fmt(r.get(f"{k}_over_floor")) for k in relits]
        lines.append(f"| {r['map']} | {r['view']} ({r['eye']}, {r['yaw']:g}) | " + " | ".join(vals) + " |")
    if any("unlit_fraction" in r for r in rows):
        lines += ["", "The same over the lit pixels only: without the sky and unlit surfaces, where the game draws "
                  "sky boxes, scrolling clouds, stars and animated shader stages that no glTF material carries "
                  "(column 'unlit': their share of the frame):", "",
                  "| map | view | unlit | " + " | ".join(head) + " |", "|---|---|---:|" + "---:|" * len(head)]
        for r in rows:
            vals = [fmt(r.get(f"{k}_lit")) for k in kinds] + [fmt(r.get(f"{k}_lit_over_floor")) for k in relits]
            lines.append(f"| {r['map']} | {r['view']} | {r.get('unlit_fraction', 0):.0%} | " + " | ".join(vals) + " |")
    lines.append("")
    for k in relits:
        for suffix, what in (("", ""), ("_lit", " (lit pixels)")):
            ratios = [r[f"{k}{suffix}_over_floor"] for r in rows if f"{k}{suffix}_over_floor" in r]
            if ratios:
                lines.append(f"- {k} / floor{what}: worst {max(ratios):.2f}, median {float(np.median(ratios)):.2f} over {len(ratios)} views (goal: at most 1.5 in every view)")
    text = "\n".join(lines) + "\n"
    stem.with_suffix(".md.tmp").write_text(text)
    stem.with_suffix(".md.tmp").replace(stem.with_suffix(".md"))
    return text


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=Path, nargs="+", required=True, help="one folder per map")
    ap.add_argument("--table", type=Path, required=True, help="writes TABLE.md and TABLE.csv")
    ap.add_argument("--side-by-side", type=Path, default=None, help="folder for MAP_K.png sheets")
    ap.add_argument("--sheet-scale", type=float, default=1.0, help="size of each image in the sheets")
    args = ap.parse_args(argv)
    rows = []
    for d in args.views:
        rs = compare_dir(d)
        rows += rs
        if args.side_by_side is not None:
            for r in rs:
                side_by_side(d, r["view"], args.side_by_side / f"{r['map']}_{r['view']}.png",
                             [k for k in kinds_in(d) if k != "lightmap"], args.sheet_scale)
    print(write_table(rows, args.table), end="")


if __name__ == "__main__":
    main(sys.argv[1:])
