"""Every OpenArena map converts to glTF 2.0 that the Khronos glTF-Validator accepts.

For every map of pak1-maps.pk3 and pak6-patch088.pk3, `q3gltf convert MAP -o OUT
--game-dir baseoa` is run twice, once to .gltf and once to .glb, and each output is
checked by the reference validator (npm gltf-validator, driven by
tests/node/validate.mjs, which also loads the external .bin and image files a .gltf
refers to): it must report 0 errors (test_output_is_valid_gltf). Warnings, infos and
hints do not fail that test; a short list of warnings that do mean broken output fails
test_no_suspicious_warnings. The validator checks far more than a viewer would
tolerate: accessor bounds and min/max, index ranges, buffer views, alignment, image
headers, material and texture references, so this catches malformed output on real,
varied maps (patches, meshes, flares, fogs, a vertex-lit map without lightmaps,
maps with 100+ lightmap pages).

All selected maps are converted by one module-scoped fixture, Q3GLTF_TEST_JOBS (default
2) conversions at a time, and validated in batches (few node start-ups) while later
conversions run; each batch's output is deleted once validated to bound disk use (set
Q3GLTF_KEEP_OUTPUT=1 to keep it under pytest's basetemp). Only maps whose tests were
selected (e.g. with -k) are converted.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

from conftest import BspMap, selected_map_cases

FORMATS = ("gltf", "glb")
JOBS = max(1, int(os.environ.get("Q3GLTF_TEST_JOBS", "2")))
BATCH = 8                # files per node invocation
MAX_UNVALIDATED = BATCH * 2 + JOBS + 1  # converted-but-not-yet-validated outputs on disk
CONVERT_TIMEOUT = 900    # seconds per conversion
KEEP_OUTPUT = os.environ.get("Q3GLTF_KEEP_OUTPUT", "") not in ("", "0")

# Validator *warnings* that still mean broken output for this tool: a texture no viewer
# can decode (the validator only warns on unknown image bytes, e.g. a TGA written as
# .png), absolute URIs (leak the build machine's paths), misspelt or out-of-list
# properties, triangle lists whose index count is not a multiple of 3, and GLB framing
# slop. Checked by test_no_suspicious_warnings, separately from the 0-errors test.
SUSPICIOUS_WARNINGS = frozenset({
    "IMAGE_UNRECOGNIZED_FORMAT", "NON_RELATIVE_URI", "UNEXPECTED_PROPERTY",
    "VALUE_NOT_IN_LIST", "MESH_PRIMITIVE_NO_POSITION", "MESH_PRIMITIVE_INCOMPATIBLE_MODE",
    "GLB_EXTRA_DATA", "GLB_UNKNOWN_CHUNK_TYPE", "BUFFER_GLB_CHUNK_TOO_BIG", "DATA_URI_GLB",
    "UNKNOWN_ASSET_MINOR_VERSION",
})


@dataclasses.dataclass
class Outcome:
    id: str
    fmt: str
    out: Path
    argv: list[str]
    returncode: int | None = None
    stderr: str = ""
    seconds: float = 0.0
    size: int = 0
    files: list[str] = dataclasses.field(default_factory=list)  # what the output dir held
    report: dict | None = None


def _convert(q3gltf: Path, baseoa: Path, bsp: Path, out: Path) -> Outcome:
    out.parent.mkdir(parents=True, exist_ok=True)
    argv = [str(q3gltf), "convert", str(bsp), "-o", str(out), "--game-dir", str(baseoa)]
    res = Outcome(id="", fmt=out.suffix[1:], out=out, argv=argv)
    t0 = time.monotonic()
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=CONVERT_TIMEOUT,
                              stdin=subprocess.DEVNULL)
        res.returncode, res.stderr = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired as exc:
        res.returncode = None
        res.stderr = f"timed out after {CONVERT_TIMEOUT}s\n{exc.stderr or ''}"
    res.seconds = time.monotonic() - t0
    if out.is_file():
        res.size = out.stat().st_size
    res.files = sorted(str(p.relative_to(out.parent)) for p in out.parent.rglob("*") if p.is_file())
    return res


def _validate(node_validator: Path, outcomes: list[Outcome]) -> None:
    """One node process for the whole batch; fills in .report for each outcome."""
    if not outcomes:
        return
    argv = ["node", "--max-old-space-size=8192", str(node_validator), *[str(o.out) for o in outcomes]]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=1800)
    reports = {}
    for line in proc.stdout.splitlines():
        line = line.strip()
        if line.startswith("{"):
            rep = json.loads(line)
            reports[rep["file"]] = rep
    for o in outcomes:
        o.report = reports.get(str(o.out)) or {
            "file": str(o.out), "errors": 1, "warnings": 0, "infos": 0, "hints": 0,
            "messages": [{"code": "NO_REPORT", "message":
                          f"validate.mjs exited {proc.returncode} without a report for this "
                          f"file; stderr: {proc.stderr.strip()[-2000:]}"}]}


@pytest.fixture(scope="module")
def validation_results(request, q3gltf, baseoa, extracted_maps, node_validator,
                       tmp_path_factory) -> dict[tuple[str, str], Outcome]:
    cases: list[BspMap] = selected_map_cases(request)
    root = tmp_path_factory.mktemp("convert")
    bsp_paths: dict[str, Path] = {}
    for case in cases:
        by_stem = {p.stem: p for p in extracted_maps(case.pk3)}
        bsp_paths[case.id] = by_stem[case.name]

    results: dict[tuple[str, str], Outcome] = {}
    slots = threading.BoundedSemaphore(MAX_UNVALIDATED)

    def job(case: BspMap, fmt: str) -> Outcome:
        slots.acquire()
        try:
            out = root / case.pak / case.name / fmt / f"{case.name}.{fmt}"
            res = _convert(q3gltf, baseoa, bsp_paths[case.id], out)
        except BaseException:
            slots.release()
            raise
        res.id = case.id
        if res.returncode != 0 or not res.out.is_file():
            _cleanup(res)
            slots.release()
        return res

    def _cleanup(res: Outcome) -> None:
        if not KEEP_OUTPUT:
            shutil.rmtree(res.out.parent, ignore_errors=True)

    def flush(batch: list[Outcome]) -> None:
        try:
            _validate(node_validator, batch)
        finally:
            for res in batch:
                _cleanup(res)
                slots.release()

    pending: list[Outcome] = []
    with concurrent.futures.ThreadPoolExecutor(max_workers=JOBS) as pool:
        futures = [pool.submit(job, case, fmt) for case in cases for fmt in FORMATS]
        for fut in concurrent.futures.as_completed(futures):
            res = fut.result()
            results[(res.id, res.fmt)] = res
            if res.returncode == 0 and res.out.is_file():
                pending.append(res)
            if len(pending) >= BATCH:
                flush(pending)
                pending = []
        flush(pending)
    return results


def _describe(res: Outcome) -> str:
    return (f"$ {' '.join(res.argv)}\n"
            f"exit {res.returncode} after {res.seconds:.1f}s, output {res.size} bytes; "
            f"files: {res.files[:20]}{' ...' if len(res.files) > 20 else ''}")


@pytest.mark.parametrize("fmt", FORMATS)
def test_output_is_valid_gltf(bsp_map, fmt, validation_results):
    res = validation_results[(bsp_map.id, fmt)]
    if res.returncode != 0:
        pytest.fail(f"conversion failed\n{_describe(res)}\nstderr:\n{res.stderr.strip()}",
                    pytrace=False)
    if res.size == 0:
        pytest.fail(f"no (or an empty) output file\n{_describe(res)}\nstderr:\n{res.stderr.strip()}",
                    pytrace=False)
    rep = res.report
    assert rep is not None, f"{_describe(res)}\nnever validated"
    summary = (f"{rep['errors']} errors, {rep['warnings']} warnings, {rep['infos']} infos, "
               f"{rep['hints']} hints; issue codes: {rep.get('codes', {})}")
    if rep["errors"]:
        lines = [f"  {m.get('code')} at {m.get('pointer') or m.get('offset')}: {m.get('message')}"
                 for m in rep.get("messages", [])]
        pytest.fail(f"glTF-Validator: {summary}\n{_describe(res)}\nfirst errors:\n"
                    + "\n".join(lines), pytrace=False)


@pytest.mark.parametrize("fmt", FORMATS)
def test_no_suspicious_warnings(bsp_map, fmt, validation_results):
    res = validation_results[(bsp_map.id, fmt)]
    if res.report is None:
        pytest.skip("not validated (conversion failed; see test_output_is_valid_gltf)")
    found = {code: n for code, n in res.report.get("codes", {}).items()
             if code in SUSPICIOUS_WARNINGS}
    assert not found, f"suspicious validator warnings {found}\n{_describe(res)}"
