#!/usr/bin/env python3
"""Speed against error: our relight against the thesis's method, on the same scenes, in
one run (compare ratios measured here, not absolute times: the machines are noisy).

The thesis's method is `--estimator tracing` (light tracing from every light, splatted onto
the vertices; `relight/src/light_tracing.rs`) on the vertex target of the scene's own
vertices (`--subdivide off`, as the thesis projected), started from its N x N grid and run
by its schemes: Table 5.1's schemes 1-5 on a 9 x 9 grid, its basic schemes (one phase of
Adam 0.1) on grids 5 to 13, Adam's step sizes 0.02-0.2 and L-BFGS on an 11 x 11 grid. Ours:
`default` and `fast` on the luxel target, and `default` on the same vertex target as the
thesis (the like-for-like error). Every configuration runs with three seeds (the estimator
draws fresh rays every evaluation; our placement subsamples by seed; `--seeds` to choose),
and `--thesis-time-limit` stops each run of the thesis's method where a sweep must fit a
budget (a GPU lease).

Writes, under OUT:
  thesis.csv       every run's curve: scene, config, seed, backend, target, time_s,
                   iteration, objective, rel_error, lights (one row per iteration)
  thesis_runs.csv  one row per run: final error, wall, time to within 1% of its best
                   error, lights, evaluations
  thesis.md        the table in the style of the thesis's Table 5.1 (median and spread over
                   seeds), the goal check per scene, the machine
  thesis.svg       per scene: error against time (the median seed of each configuration)
                   and the Pareto front of final error against wall time (every run)

    python3 benches/thesis.py --bin target/release/q3gltf --game-dir DIR --out docs/bench
    python3 benches/thesis.py --bin ... --quick        (the bundled sample, small budgets)

The full sweep (eleven scenes, 18 configurations, three seeds, two backends) takes hours
on a GPU; a lent one comes for minutes. `--resume` keeps the runs OUT's CSVs already
hold (the same scene, configuration, backend and seed are not run again) and
`--budget SECONDS` starts no run after that many seconds, so the sweep can go on over
several leases; the files are rewritten after every run, so a sweep killed from outside
keeps what it finished. Each run records the machine it ran on (`machine` in
thesis_runs.csv), and thesis.md lists them.

Scenes (`--scenes`): `sample` (the bundled sample), `fixture:NAME` (one of our q3map2-compiled
ground-truth maps, `tests/fixtures/q3map2/maps/NAME.bsp`, converted with its shaders: `point`
and `pillar` are lit by point lights alone, the one kind of light the thesis's estimator
has), map names inside the game dirs' pk3s (oa_dm1, oa_dm3 with patches, a large map, the
truth-set OACMP maps: pass `--game-dir` once for baseoa and once more for the OACMP pack),
or converted scenes (.glb). Every scene is relit from scratch: no source lights are read.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scaling import machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEEDS = [1, 2, 3]
# The scenes: the sample, two ground-truth fixtures lit by point lights only, oa_dm1,
# oa_dm3 (patches), a large map (ctf_compromise: 102 lightmap pages, the most of baseoa's maps) and
# the truth set.
SCENES = ["sample", "fixture:point", "fixture:pillar", "oa_dm1", "oa_dm3", "ctf_compromise", "oacmpdm1", "oacmpdm2", "oacmpdm3", "oacmpdm4", "oacmpctf1"]


def configs(quick: bool, rays: int, cap: int | None) -> list[dict]:
    """Every configuration: name, arguments, whether anything in it is random."""
    out = []
    ours = [("ours default, luxel", ["--scheme", "default"]), ("ours fast, luxel", ["--scheme", "fast"]),
            ("ours default, vertex", ["--scheme", "default", "--target", "vertex", "--subdivide", "off"])]
    for name, args in ours:
        out.append({"name": name, "method": "ours", "args": args})
    tr = ["--estimator", "tracing", "--target", "vertex", "--subdivide", "off", "--rays", str(rays)]
    if quick:
        thesis = [("thesis3, grid 3", ["--init", "grid:3", "--scheme", "thesis3"]), ("adam 0.1, grid 3", ["--init", "grid:3", "--scheme", "adam:0.1"]),
                  ("lbfgs 1.0, grid 3", ["--init", "grid:3", "--scheme", "lbfgs:1.0"])]
    else:
        thesis = [(f"thesis{k}, grid 9", ["--init", "grid:9", "--scheme", f"thesis{k}"]) for k in range(1, 6)]
        thesis += [(f"adam 0.1, grid {n}", ["--init", f"grid:{n}", "--scheme", "adam:0.1"]) for n in (5, 7, 9, 11, 13)]
        thesis += [(f"adam {s}, grid 11", ["--init", "grid:11", "--scheme", f"adam:{s}"]) for s in (0.02, 0.05, 0.2)]
        thesis += [("lbfgs 1.0, grid 11", ["--init", "grid:11", "--scheme", "lbfgs:1.0"])]
    for name, args in thesis:
        out.append({"name": name, "method": "thesis", "args": tr + args + (["--max-iterations", str(cap)] if cap else [])})
    return out


FIXTURES = ROOT / "tests/fixtures/q3map2"


def label(scene: str) -> str:
    """The name a scene is reported under."""
    return Path(scene).stem if scene.endswith((".glb", ".gltf")) else scene


def convert(binary: str, scene: str, game_dirs: list[str], work: Path) -> Path:
    """The scene as a converted glTF under `work` (a .glb path is used as it is)."""
    if scene.endswith(".glb") or scene.endswith(".gltf"):
        return Path(scene).resolve()
    dst = work / f"{scene.replace(':', '-')}.glb"
    if not dst.exists():
        dirs = [x for g in game_dirs for x in ("--game-dir", g)]
        if scene == "sample":
            src = [str(ROOT / "samples/sample/maps/sample.bsp")]
        elif scene.startswith("fixture:"):
            bsp = FIXTURES / "maps" / f"{scene.split(':', 1)[1]}.bsp"
            if not bsp.is_file():
                sys.exit(f"thesis.py: no fixture {bsp}")
            src = [str(bsp), *dirs, "--game-dir", str(FIXTURES / "scripts")]
        else:
            if not game_dirs:
                sys.exit(f"thesis.py: scene {scene} is a map name: pass --game-dir")
            src = [scene, *dirs]
        subprocess.run([binary, "convert", *src, "-q", "-o", str(dst)], check=True)
    return dst


def run_one(binary: str, glb: Path, cfg: dict, backend: str, seed: int, time_limit: float | None, work: Path) -> dict | None:
    """One relight; `time_limit`: seconds (its `--time-limit`), or none."""
    rep = work / "r.json"
    cmd = [binary, "relight", str(glb), "-o", str(work / "out.glb"), "-q", "--backend", backend, "--seed", str(seed), "--report", str(rep), *cfg["args"]]
    if time_limit:
        cmd += ["--time-limit", str(time_limit)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        print(f"  failed: {' '.join(cmd)}\n  {p.stderr.strip().splitlines()[-1] if p.stderr.strip() else ''}", file=sys.stderr)
        return None
    return json.loads(rep.read_text())


def summary(r: dict) -> dict:
    """Final error, wall, time to within 1% of the run's best error, lights, evaluations."""
    curve = [(it["time_s"], it["rel_error"]) for it in r["iterations"] if not it.get("placement")]
    best = min([e for _, e in curve] + [r["rel_error_final"]])
    t_close = next((t for t, e in curve if e <= 1.01 * best), r["total_time_s"])
    return {"error": r["rel_error_final"], "wall": r["total_time_s"], "t_within_1pct": t_close, "lights": len(r["lights"]), "evaluations": r["evaluations"], "iterations": len(curve)}


COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#e6550d"]


def panel(x0: float, y0: float, title: str, xlabel: str, series: list[tuple[str, list[tuple[float, float]], str, bool]], legend: bool) -> str:
    """A panel with a log time axis and a linear error axis; series: (label, points, colour, markers only)."""
    w, h, l, r, t, b = 520, 380, 60, 10, 30, 50
    pts = [p for _, s, _, _ in series for p in s if p[0] > 0]
    if not pts:
        return ""
    x_lo = math.floor(math.log10(min(p[0] for p in pts)))
    x_hi = max(math.ceil(math.log10(max(p[0] for p in pts))), x_lo + 1)
    y_hi = min(1.05, max(p[1] for p in pts) * 1.05)
    y_lo = max(0.0, min(p[1] for p in pts) * 0.9)
    sx = lambda v: x0 + l + (math.log10(max(v, 10 ** x_lo)) - x_lo) / (x_hi - x_lo) * (w - l - r)
    sy = lambda v: y0 + t + (y_hi - min(v, y_hi)) / max(y_hi - y_lo, 1e-9) * (h - t - b)
    out = [f'<text x="{x0 + w / 2}" y="{y0 + 18}" text-anchor="middle" font-size="13">{title}</text>']
    for d in range(x_lo, x_hi + 1):
        x = sx(10 ** d)
        out.append(f'<line x1="{x:.1f}" y1="{y0 + t}" x2="{x:.1f}" y2="{y0 + h - b}" stroke="#ddd"/>')
        out.append(f'<text x="{x:.1f}" y="{y0 + h - b + 16}" text-anchor="middle" font-size="11">10<tspan dy="-5" font-size="8">{d}</tspan></text>')
    for k in range(6):
        v = y_lo + (y_hi - y_lo) * k / 5
        y = sy(v)
        out.append(f'<line x1="{x0 + l}" y1="{y:.1f}" x2="{x0 + w - r}" y2="{y:.1f}" stroke="#eee"/>')
        out.append(f'<text x="{x0 + l - 6}" y="{y + 4:.1f}" text-anchor="end" font-size="11">{v:.2f}</text>')
    out.append(f'<text x="{x0 + w / 2}" y="{y0 + h - 14}" text-anchor="middle" font-size="12">{xlabel}</text>')
    cy = y0 + (t + h - b) / 2
    out.append(f'<text x="{x0 + 14}" y="{cy}" font-size="12" transform="rotate(-90 {x0 + 14} {cy})" text-anchor="middle">relative error</text>')
    ly = y0 + t + 8
    for label, s, color, markers in series:
        s = [p for p in s if p[0] > 0]
        if not s:
            continue
        if markers:
            out.extend(f'<circle cx="{sx(x):.1f}" cy="{sy(y):.1f}" r="3" fill="{color}"/>' for x, y in s)
        else:
            out.append(f'<polyline points="{" ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in s)}" fill="none" stroke="{color}" stroke-width="1.5"/>')
        if legend:
            out.append(f'<line x1="{x0 + w - 200}" y1="{ly}" x2="{x0 + w - 182}" y2="{ly}" stroke="{color}" stroke-width="3"/>')
            out.append(f'<text x="{x0 + w - 178}" y="{ly + 4}" font-size="10">{label}</text>')
            ly += 12
    return "\n".join(out)


def pareto(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    front, best = [], math.inf
    for t, e in sorted(points):
        if e < best:
            front.append((t, e))
            best = e
    return front


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--game-dir", action="append", default=[], help="a game dir for map names and fixtures' textures (repeat: baseoa, then the OACMP pack)")
    ap.add_argument("--scenes", help="comma-separated: sample, fixture:NAME, map names, or converted scenes (.glb); default: the issue's eleven, or the sample with --quick")
    ap.add_argument("--backends", default="cpu", help="comma-separated: cpu, wgpu")
    ap.add_argument("--rays", type=int, default=100_000, help="rays per light of the thesis's estimator (the thesis: 100,000)")
    ap.add_argument("--max-iterations", type=int, help="caps every phase of the thesis's runs")
    ap.add_argument("--time-limit", type=float, help="seconds per run")
    ap.add_argument("--thesis-time-limit", type=float, help="seconds per run of the thesis's method only (a budget where the whole sweep must fit a lease)")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)), help="comma-separated seeds (default: three)")
    ap.add_argument("--quick", action="store_true", help="three small thesis configurations, 10,000 rays per light, 20 iterations a phase; on the bundled sample unless --scenes")
    ap.add_argument("--resume", action="store_true", help="keep the runs OUT's CSVs already hold and do only the others (a sweep over several leases)")
    ap.add_argument("--budget", type=float, help="start no run after this many seconds (what is done is written after every run)")
    a = ap.parse_args()
    seeds = [int(x) for x in a.seeds.split(",")]
    scenes = a.scenes.split(",") if a.scenes else ["sample"] if a.quick else SCENES
    rays = min(a.rays, 10_000) if a.quick else a.rays
    cap = a.max_iterations or (20 if a.quick else None)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    runs, curves = (read_previous(out) if a.resume else ([], []))
    done = {(r["scene"], r["config"], r["backend"], r["seed"]) for r in runs}
    here = machine()
    started = time.monotonic()
    settings = {"rays": rays, "cap": cap, "seeds": seeds, "thesis_time_limit": a.thesis_time_limit, "time_limit": a.time_limit}
    left = 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for scene in scenes:
            glb = None
            for cfg in configs(a.quick, rays, cap):
                for backend in a.backends.split(","):
                    for seed in seeds:
                        if (label(scene), cfg["name"], backend, seed) in done:
                            continue
                        if a.budget is not None and time.monotonic() - started > a.budget:
                            left += 1
                            continue
                        glb = glb or convert(a.bin, scene, a.game_dir, work)
                        limit = a.thesis_time_limit if cfg["method"] == "thesis" and a.thesis_time_limit else a.time_limit
                        r = run_one(a.bin, glb, cfg, backend, seed, limit, work)
                        if r is None:
                            continue
                        s = summary(r)
                        target = r["target_space"]
                        runs.append({"scene": label(scene), "config": cfg["name"], "method": cfg["method"], "backend": backend, "seed": seed, "target": target, **s, "adapter": r["backend"], "machine": here})
                        for it in r["iterations"]:
                            if not it.get("placement"):
                                curves.append({"scene": label(scene), "config": cfg["name"], "seed": seed, "backend": backend, "target": target, "time_s": it["time_s"], "iteration": it["iteration"], "objective": it["objective"], "rel_error": it["rel_error"], "lights": it["lights"]})
                        print(f"{label(scene):10} {cfg['name']:24} {backend:4} seed {seed}: error {s['error']:.4f}, {s['wall']:.1f} s, {s['lights']} lights, {s['evaluations']} evaluations", flush=True)
                        write(out, runs, curves, list(map(label, scenes)), settings)
    write(out, runs, curves, list(map(label, scenes)), settings)
    if left:
        print(f"thesis.py: the budget ({a.budget:g} s) left {left} runs undone: run again with --resume", file=sys.stderr)
    print((out / "thesis.md").read_text())


RUN_FIELDS = ["scene", "config", "method", "backend", "seed", "target", "error", "wall", "t_within_1pct", "lights", "evaluations", "iterations", "adapter", "machine"]
CURVE_FIELDS = ["scene", "config", "seed", "backend", "target", "time_s", "iteration", "objective", "rel_error", "lights"]


def read_previous(out: Path) -> tuple[list[dict], list[dict]]:
    """The runs and curves OUT's CSVs hold (numbers as numbers; a run from before the
    machine was recorded has it empty)."""
    runs, curves = [], []
    num = lambda v: float(v) if v not in ("", None) else math.nan
    if (out / "thesis_runs.csv").exists():
        with open(out / "thesis_runs.csv", newline="") as f:
            for r in csv.DictReader(f):
                runs.append({**{k: r.get(k) or "" for k in RUN_FIELDS}, "seed": int(r["seed"]), "error": num(r["error"]), "wall": num(r["wall"]), "t_within_1pct": num(r["t_within_1pct"]),
                             "lights": int(r["lights"]), "evaluations": int(r["evaluations"]), "iterations": int(r["iterations"])})
    if (out / "thesis.csv").exists():
        with open(out / "thesis.csv", newline="") as f:
            for c in csv.DictReader(f):
                curves.append({**c, "seed": int(c["seed"]), "time_s": num(c["time_s"]), "iteration": int(c["iteration"]), "objective": num(c["objective"]), "rel_error": num(c["rel_error"]), "lights": int(c["lights"])})
    return runs, curves


def write(out: Path, runs: list[dict], curves: list[dict], scenes: list[str], settings: dict) -> None:
    """thesis.csv, thesis_runs.csv, thesis.md and thesis.svg from every run so far, each
    written under a temporary name and renamed."""
    def replace(name: str, fill) -> None:
        tmp = out / f".{name}.tmp"
        with open(tmp, "w", newline="") as f:
            fill(f)
        tmp.replace(out / name)

    def table(fields, rows):
        def fill(f):
            w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        return fill
    replace("thesis.csv", table(CURVE_FIELDS, curves))
    replace("thesis_runs.csv", table(RUN_FIELDS, runs))
    md, svg = render(runs, curves, [s for s in scenes if any(r["scene"] == s for r in runs)] + sorted({r["scene"] for r in runs} - set(scenes)), settings)
    replace("thesis.md", lambda f: f.write(md))
    replace("thesis.svg", lambda f: f.write(svg))


def render(runs: list[dict], curves: list[dict], scenes: list[str], settings: dict) -> tuple[str, str]:
    """The table (Markdown) and the plots (SVG) of `runs` and their `curves`."""
    rays, cap, seeds = settings["rays"], settings["cap"], settings["seeds"]
    adapters = sorted({r["adapter"] for r in runs if r.get("adapter")})
    machines = sorted({r["machine"] for r in runs if r.get("machine")})
    unknown = sum(1 for r in runs if not r.get("machine"))
    md = [f"# Our relight against the thesis's method\n", f"Machine{'s' if len(machines) > 1 else ''}: {'; '.join(machines) or 'not recorded'}{f' (and {unknown} runs from before machines were recorded)' if unknown and machines else ''}; backends as the runs named them: {'; '.join(adapters) or 'not recorded'}. Rays per light of the thesis's estimator: {rays}; "
          f"phase cap of its runs: {cap or 'none (the thesis: Adam 400, L-BFGS until it stops)'}; seeds {seeds}"
          + (f"; each run of the thesis's method stopped after {settings['thesis_time_limit']:g} s" if settings["thesis_time_limit"] else "")
          + (f"; each run stopped after {settings['time_limit']:g} s" if settings["time_limit"] else "") + ".",
          "Errors are each run's relative error on its own target (luxel or vertex rows; `ours default, vertex` and the thesis's runs share the vertex rows). "
          "Median over seeds, spread min-max; the time to within 1% is when the run's curve first came within 1% of its own best error.\n"]
    svg, y = [], 0
    for scene in scenes:
        md += [f"## {scene}\n", "| configuration | backend | target | final error (median) | spread | time to within 1% (s) | wall (s) | lights | evaluations |", "|---|---|---|---:|---:|---:|---:|---:|---:|"]
        groups: dict[tuple[str, str], list[dict]] = {}
        for r in runs:
            if r["scene"] == scene:
                groups.setdefault((r["config"], r["backend"]), []).append(r)
        med = {}
        for (name, backend), rs in groups.items():
            e = [r["error"] for r in rs]
            m = {"error": statistics.median(e), "wall": statistics.median(r["wall"] for r in rs), "t1": statistics.median(r["t_within_1pct"] for r in rs), "method": rs[0]["method"], "target": rs[0]["target"]}
            med[(name, backend)] = m
            md.append(f"| {name} | {backend} | {m['target']} | {m['error']:.4f} | {min(e):.4f}-{max(e):.4f} | {m['t1']:.1f} | {m['wall']:.1f} | {statistics.median(r['lights'] for r in rs):.0f} | {statistics.median(r['evaluations'] for r in rs):.0f} |")
        thesis = {k: v for k, v in med.items() if v["method"] == "thesis"}
        if thesis:
            bk, bv = min(thesis.items(), key=lambda kv: kv[1]["error"])
            md.append(f"\nBest thesis configuration: {bk[0]} ({bk[1]}), error {bv['error']:.4f} in {bv['wall']:.1f} s.")
            for (name, backend), v in med.items():
                if name.startswith("ours default"):
                    ok_e, ok_t = v["error"] <= bv["error"], v["wall"] <= bv["wall"] / 10
                    md.append(f"Goal, {name} ({backend}): error {v['error']:.4f} {'<=' if ok_e else '>'} {bv['error']:.4f}; "
                              f"wall {v['wall']:.1f} s {'<=' if ok_t else '>'} a tenth of {bv['wall']:.1f} s: {'met' if ok_e and ok_t else 'NOT met'}.")
        md.append("")
        # Curves: the median seed of each configuration; Pareto: every run.
        series, colours = [], {}
        for k, (name, backend) in enumerate(sorted(groups)):
            colours[(name, backend)] = COLORS[k % len(COLORS)]
            rs = sorted(groups[(name, backend)], key=lambda r: r["error"])
            mid = rs[len(rs) // 2]
            pts = [(c["time_s"], c["rel_error"]) for c in curves if c["scene"] == scene and c["config"] == name and c["backend"] == backend and c["seed"] == mid["seed"]]
            series.append((f"{name} ({backend})", pts, colours[(name, backend)], False))
        svg.append(panel(0, y, f"{scene}: error against time (median seed)", "seconds", series, True))
        allpts = [(r["wall"], r["error"]) for r in runs if r["scene"] == scene]
        front = pareto(allpts)
        scat = [(f"{n} ({b})", [(r["wall"], r["error"]) for r in groups[(n, b)]], colours[(n, b)], True) for (n, b) in sorted(groups)]
        svg.append(panel(540, y, f"{scene}: final error against wall time (Pareto front)", "wall seconds", scat + [("Pareto front", front, "#000", False)], False))
        y += 400
    return "\n".join(md) + "\n", f'<svg xmlns="http://www.w3.org/2000/svg" width="1080" height="{max(y, 400)}" font-family="sans-serif">\n<rect width="100%" height="100%" fill="white"/>\n' + "\n".join(svg) + "\n</svg>\n"


if __name__ == "__main__":
    main()
