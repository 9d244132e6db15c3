#!/usr/bin/env python3
"""Scaling benchmark of `q3gltf relight`: time per stage against the number of lights and
against the number of rows, on each backend, in one run (compare ratios and exponents,
not absolute times: the machines are noisy).

Lights: the scene started from N point lights at random lightmapped vertices (0.5 m off
the surface, fixed seed), `--init input --max-iterations 2`, N from 8 to 1024. Rows:
16 such lights, the vertex target at several subdivision lengths. For each stage the
exponent `k` of `time ~ size^k` is fitted by least squares on the log-log points (those
above 20 ms). Writes `OUT/scaling.csv` (every run), `OUT/scaling.md` (tables, exponents,
the machine) and `OUT/scaling.svg` (log-log plots), and prints the Markdown.

    python3 benches/scaling.py --bin target/release/q3gltf --scene oa_dm1.glb --out docs/bench
    python3 benches/scaling.py ... --quick      (the bundled sample's sizes: a minute)

Needs numpy (tests/python/requirements.txt).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import random
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from gltf_io import accessor, read_glb  # noqa: E402

STAGES = ["rows", "bases", "start", "optimise", "opt: traces", "opt: evaluating", "prune", "gamma", "total"]


def with_lights(src: Path, n: int, dst: Path, seed: int = 1) -> None:
    """`src` (a .glb) with `n` point lights at random lightmapped vertices."""
    doc, binary = read_glb(src)
    pts = []
    for m in doc["meshes"]:
        for p in m["primitives"]:
            mat = doc["materials"][p["material"]] if "material" in p else {}
            if mat.get("occlusionTexture") is None or "NORMAL" not in p["attributes"]:
                continue
            pts.append(accessor(doc, binary, p["attributes"]["POSITION"]) + 0.5 * accessor(doc, binary, p["attributes"]["NORMAL"]))
    pts = np.concatenate(pts)
    rng = random.Random(seed)
    chosen = [pts[rng.randrange(len(pts))] for _ in range(n)]
    doc.setdefault("extensions", {})["KHR_lights_punctual"] = {"lights": [{"type": "point", "color": [1, 1, 1], "intensity": 200.0}] * n}
    if "KHR_lights_punctual" not in doc.setdefault("extensionsUsed", []):
        doc["extensionsUsed"].append("KHR_lights_punctual")
    base = len(doc["nodes"])
    for k, p in enumerate(chosen):
        doc["nodes"].append({"name": f"bench_{k}", "translation": [float(x) for x in p], "extensions": {"KHR_lights_punctual": {"light": k}}})
    doc["scenes"][doc.get("scene", 0)]["nodes"].extend(range(base, base + n))
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    b = binary + b"\0" * (-len(binary) % 4)
    dst.write_bytes(struct.pack("<3I", 0x46546C67, 2, 28 + len(js) + len(b)) + struct.pack("<2I", len(js), 0x4E4F534A) + js
                    + struct.pack("<2I", len(b), 0x004E4942) + b)


def relight(binary: str, src: Path, backend: str, extra: list[str], work: Path) -> dict | None:
    rep = work / "report.json"
    res = subprocess.run([binary, "relight", str(src), "-o", str(work / "out.glb"), "--init", "input", "--max-iterations", "2",
                          "--backend", backend, "--report", str(rep), "-q", *extra], capture_output=True, text=True)
    if res.returncode != 0:
        print(f"  {backend} {extra}: failed: {res.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
        return None
    r = json.loads(rep.read_text())
    st = dict(r["stage_times_s"])
    out = {"rows": st.get("rows", 0.0), "bases": sum(v for k, v in st.items() if k.startswith("bases")),
           "start": st.get("start", 0.0), "optimise": st.get("optimise", 0.0), "prune": sum(t for n, t in st.items() if n == "prune" or n.startswith("prune:")),
           "gamma": st.get("gamma", 0.0), "total": r["total_time_s"]}
    # The optimise stage is the scheme's phases; of their time, what re-traced the shadows
    # of lights that moved (how often depends on the path, not on the size) and the rest.
    main = [p for p in r["phases"] if p["name"].startswith(f"{r['scheme']} phase")]
    out["opt: traces"] = sum(p.get("trace_s", 0.0) for p in main)
    out["opt: evaluating"] = max(out["optimise"] - out["opt: traces"], 0.0)
    out.update(backend_name=r["backend"], problem_rows=r["problem_rows"], lights_out=len(r["lights"]), rays=r["rays_traced"],
               opt_evaluations=sum(p["evaluations"] for p in main), opt_rays=sum(p.get("rays", 0) for p in main))
    return out


def exponent(xs: list[float], ys: list[float]) -> float | None:
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0.02]
    if len(pts) < 2 or len({p[0] for p in pts}) < 2:
        return None
    a = np.array(pts)
    return float(np.polyfit(a[:, 0], a[:, 1], 1)[0])


COLORS = {"rows": "#1f77b4", "bases": "#ff7f0e", "start": "#2ca02c", "optimise": "#d62728", "opt: traces": "#e377c2",
          "opt: evaluating": "#8c564b", "prune": "#9467bd", "gamma": "#bcbd22", "total": "#000000"}


def svg_panel(x0: float, title: str, xlabel: str, series: dict, exps: dict) -> str:
    """One log-log panel at horizontal offset x0; series[(stage, backend)] = [(x, t)]."""
    w, h, l, r, t, b = 460, 360, 60, 10, 40, 50
    pts = [p for s in series.values() for p in s if p[0] > 0 and p[1] > 0]
    if not pts:
        return ""
    lx = [math.log10(p[0]) for p in pts]
    ly = [math.log10(max(p[1], 1e-3)) for p in pts]
    x_lo, x_hi = math.floor(min(lx)), math.ceil(max(lx))
    y_lo, y_hi = math.floor(min(ly)), math.ceil(max(ly))
    x_hi, y_hi = max(x_hi, x_lo + 1), max(y_hi, y_lo + 1)
    sx = lambda v: x0 + l + (math.log10(v) - x_lo) / (x_hi - x_lo) * (w - l - r)
    sy = lambda v: t + (y_hi - math.log10(max(v, 1e-3))) / (y_hi - y_lo) * (h - t - b)
    out = [f'<text x="{x0 + w / 2}" y="20" text-anchor="middle" font-size="14">{title}</text>']
    for d in range(x_lo, x_hi + 1):
        x = sx(10 ** d)
        out.append(f'<line x1="{x:.1f}" y1="{t}" x2="{x:.1f}" y2="{h - b}" stroke="#ddd"/>')
        out.append(f'<text x="{x:.1f}" y="{h - b + 16}" text-anchor="middle" font-size="11">10<tspan dy="-5" font-size="8">{d}</tspan></text>')
    for d in range(y_lo, y_hi + 1):
        y = sy(10 ** d)
        out.append(f'<line x1="{x0 + l}" y1="{y:.1f}" x2="{x0 + w - r}" y2="{y:.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{x0 + l - 6}" y="{y + 4:.1f}" text-anchor="end" font-size="11">10<tspan dy="-5" font-size="8">{d}</tspan></text>')
    out.append(f'<text x="{x0 + w / 2}" y="{h - 12}" text-anchor="middle" font-size="12">{xlabel}</text>')
    out.append(f'<text x="{x0 + 14}" y="{(t + h - b) / 2}" font-size="12" transform="rotate(-90 {x0 + 14} {(t + h - b) / 2})" text-anchor="middle">seconds</text>')
    legend_y = t + 6
    for (stage, backend), s in sorted(series.items()):
        s = [p for p in s if p[0] > 0 and p[1] > 0]
        if not s:
            continue
        dash = ' stroke-dasharray="5,3"' if backend != "cpu" else ""
        path = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in s)
        out.append(f'<polyline points="{path}" fill="none" stroke="{COLORS[stage]}" stroke-width="1.6"{dash}/>')
        k = exps.get((stage, backend))
        label = f"{stage} {backend}" + (f" k={k:.2f}" if k is not None else "")
        out.append(f'<line x1="{x0 + l + 8}" y1="{legend_y}" x2="{x0 + l + 28}" y2="{legend_y}" stroke="{COLORS[stage]}" stroke-width="2"{dash}/>')
        out.append(f'<text x="{x0 + l + 32}" y="{legend_y + 4}" font-size="10">{label}</text>')
        legend_y += 13
    return "\n".join(out)


def machine() -> str:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", required=True)
    ap.add_argument("--scene", required=True, type=Path, help="a converted scene (.glb)")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--quick", action="store_true", help="fewer and smaller points")
    ap.add_argument("--backends", default="cpu,wgpu")
    ap.add_argument("--sweeps", default="lights,rows", help="which sweeps to run: lights, rows or both")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    counts = [8, 32, 128] if a.quick else [8, 32, 128, 512, 1024]
    lengths = [2.0, 1.0, 0.5] if a.quick else [4.0, 2.0, 1.0, 0.5, 0.25]
    backends = a.backends.split(",")
    sweeps = [w for w in ["lights", "rows"] if w in a.sweeps.split(",")]
    runs = []
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        for n in counts if "lights" in sweeps else []:
            src = work / f"lights{n}.glb"
            with_lights(a.scene, n, src)
            for be in backends:
                r = relight(a.bin, src, be, [], work)
                if r:
                    runs.append({"sweep": "lights", "size": n, "backend": be, **r})
                    print(f"  lights {n:5d} {be:4s}: {r['total']:.2f} s", file=sys.stderr)
        src = work / "lights16.glb"
        with_lights(a.scene, 16, src)
        for m in lengths if "rows" in sweeps else []:
            for be in backends:
                r = relight(a.bin, src, be, ["--target", "vertex", "--subdivide", str(m)], work)
                if r:
                    runs.append({"sweep": "rows", "size": r["problem_rows"], "subdivide_m": m, "backend": be, **r})
                    print(f"  rows {r['problem_rows']:7d} {be:4s}: {r['total']:.2f} s", file=sys.stderr)
    keys = ["sweep", "size", "backend", "subdivide_m", *STAGES, "problem_rows", "lights_out", "rays", "opt_evaluations", "opt_rays", "backend_name"]
    with open(a.out / "scaling.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        wr.writeheader()
        for r in runs:
            wr.writerow(r)
    exps: dict = {}
    for sweep in sweeps:
        for be in backends:
            sel = [r for r in runs if r["sweep"] == sweep and r["backend"] == be]
            for s in STAGES:
                exps[(sweep, s, be)] = exponent([r["size"] for r in sel], [r[s] for r in sel])
    names = sorted({r["backend_name"] for r in runs})
    md = [f"# relight scaling ({'quick, ' if a.quick else ''}scene {a.scene.name})", "",
          f"Machine: {machine()}. Backends: {'; '.join(names)}.", "",
          "Exponent k of time ~ size^k per stage (least squares on log-log, points above 20 ms; blank: too fast to fit). "
          "`optimise` is the scheme's phases, split into `opt: traces` (re-tracing the shadows of lights that moved: how "
          "often that happens depends on the fit's path) and `opt: evaluating` (the rest: the objective and its gradient); "
          "`prune` is the stages after the phases (the terms' decisions, pruning, merging, the polish), `gamma` the one "
          "after them: the final exact refit and the compile's gamma estimate (these starts are `--init input`, which "
          "estimates it); "
          "the rows tables give the evaluations and the rays behind each:", "",
          "| sweep | backend | " + " | ".join(STAGES) + " |", "|---|---|" + "---:|" * len(STAGES)]
    for sweep in sweeps:
        for be in backends:
            cells = [f"{exps[(sweep, s, be)]:.2f}" if exps[(sweep, s, be)] is not None else "" for s in STAGES]
            md.append(f"| {sweep} | {be} | " + " | ".join(cells) + " |")
    for sweep, label in [(w, w) for w in sweeps]:
        md += ["", f"Seconds per stage against {label}:", "",
               f"| {label} | backend | " + " | ".join(STAGES) + " | lights kept | opt: evaluations | opt: rays |",
               "|---:|---|" + "---:|" * (len(STAGES) + 3)]
        for r in sorted((r for r in runs if r["sweep"] == sweep), key=lambda r: (r["backend"], r["size"])):
            md.append(f"| {r['size']} | {r['backend']} | " + " | ".join(f"{r[s]:.2f}" for s in STAGES)
                      + f" | {r['lights_out']} | {r['opt_evaluations']} | {r['opt_rays']} |")
    (a.out / "scaling.md").write_text("\n".join(md) + "\n")
    panels = []
    for k, (sweep, xlabel) in enumerate([p for p in [("lights", "lights at the start"), ("rows", "rows (vertex target)")] if p[0] in sweeps]):
        series = {}
        for be in backends:
            for s in STAGES:
                pts = sorted((r["size"], r[s]) for r in runs if r["sweep"] == sweep and r["backend"] == be)
                series[(s, be)] = pts
        panels.append(svg_panel(k * 470, f"time per stage against {sweep} (solid cpu, dashed wgpu)", xlabel, series,
                                {(s, be): exps[(sweep, s, be)] for s in STAGES for be in backends}))
    svg = ['<svg xmlns="http://www.w3.org/2000/svg" width="940" height="380" font-family="sans-serif">',
           '<rect width="100%" height="100%" fill="white"/>', *panels,
           f'<text x="10" y="374" font-size="10">{machine()}; {"; ".join(names)}</text>', "</svg>"]
    (a.out / "scaling.svg").write_text("\n".join(svg) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
