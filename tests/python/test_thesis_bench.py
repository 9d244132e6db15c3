"""Self-test of benches/thesis.py's sweep over several leases (`--resume`, `--budget`), with
a stand-in for `q3gltf relight` that writes a made-up report and logs each call (no q3gltf
binary or game data needed; the real runs are the benchmark's own, `make bench-quick`).

A sweep taken a lease at a time must run each (scene, configuration, backend, seed) once,
keep what earlier leases wrote, and stop starting runs when its budget is spent, leaving
its files whole.
"""
from __future__ import annotations

import csv
import stat
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
THESIS = REPO_ROOT / "benches" / "thesis.py"

# The stand-in: `relight SCENE -o OUT ... --seed S --report R ...` writes a report whose
# error depends on the seed and logs the call's configuration and seed.
FAKE = """#!{python}
import json, sys
a = sys.argv[1:]
assert a[0] == "relight", a
seed = int(a[a.index("--seed") + 1])
tracing = "tracing" in a
with open({log!r}, "a") as f:
    f.write(" ".join(a[a.index("--seed") - 2:a.index("--seed") + 2]) + " " + (a[a.index("--scheme") + 1] if "--scheme" in a else "") + " " + ("vertex" if "vertex" in a else "luxel") + "\\n")
its = [{{"time_s": 0.1 * k, "iteration": k, "objective": 1.0 / k, "rel_error": 0.5 / k + 0.01 * seed, "lights": 3}} for k in range(1, 4)]
json.dump({{"backend": "cpu (fake)", "target_space": "vertex" if "vertex" in a else "luxel", "iterations": its,
           "rel_error_final": its[-1]["rel_error"] + (0.3 if tracing else 0.0), "total_time_s": 0.5, "lights": [{{}}] * 3,
           "evaluations": 3}}, open(a[a.index("--report") + 1], "w"))
"""


def sweep(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(THESIS), "--quick", "--bin", str(tmp / "fake"), "--scenes", str(tmp / "scene.glb"), "--out", str(tmp / "out"), *args],
                          capture_output=True, text=True, timeout=120)


def runs(tmp: Path) -> list[dict]:
    with open(tmp / "out" / "thesis_runs.csv", newline="") as f:
        return list(csv.DictReader(f))


def calls(tmp: Path) -> list[str]:
    log = tmp / "calls.log"
    return log.read_text().splitlines() if log.exists() else []


def test_a_sweep_goes_on_where_the_last_lease_stopped(tmp_path: Path) -> None:
    fake = tmp_path / "fake"
    fake.write_text(FAKE.format(python=sys.executable, log=str(tmp_path / "calls.log")))
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    (tmp_path / "scene.glb").write_bytes(b"")  # used as it is: never read by the stand-in

    # The quick form's six configurations, one seed.
    p = sweep(tmp_path, "--seeds", "1")
    assert p.returncode == 0, p.stderr
    assert len(calls(tmp_path)) == 6 and len(runs(tmp_path)) == 6
    first = runs(tmp_path)
    assert all(r["machine"] and r["adapter"] == "cpu (fake)" for r in first)

    # A second lease with another seed: only that seed's runs, the first lease's kept as
    # they were (a run already in the CSVs is never run again).
    p = sweep(tmp_path, "--seeds", "1,2", "--resume")
    assert p.returncode == 0, p.stderr
    new = calls(tmp_path)[6:]
    assert len(new) == 6 and all(" 2 " in c for c in new), new
    both = runs(tmp_path)
    assert len(both) == 12 and both[:6] == first
    assert sorted({(r["config"], r["seed"]) for r in both}) == sorted({(r["config"], s) for r in first for s in ("1", "2")})
    curves = list(csv.DictReader(open(tmp_path / "out" / "thesis.csv", newline="")))
    assert len(curves) == 12 * 3, "every run's curve kept"

    # A spent budget starts nothing, says what is left, and leaves the files whole.
    p = sweep(tmp_path, "--seeds", "1,2,3", "--resume", "--budget", "0")
    assert p.returncode == 0, p.stderr
    assert len(calls(tmp_path)) == 12
    assert "left 6 runs undone" in p.stderr
    assert runs(tmp_path) == both
    md = (tmp_path / "out" / "thesis.md").read_text()
    assert "## scene" in md and "Best thesis configuration" in md
    assert not list((tmp_path / "out").glob(".*.tmp")), "no half-written file left"

    # Without --resume the sweep starts afresh.
    p = sweep(tmp_path, "--seeds", "3")
    assert p.returncode == 0, p.stderr
    assert len(runs(tmp_path)) == 6 and {r["seed"] for r in runs(tmp_path)} == {"3"}
