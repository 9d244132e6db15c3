"""Shared fixtures for q3gltf's Python test harness.

Run from the repository root as ``.venv/bin/python -m pytest tests/python``.

Environment:
  Q3GLTF_BIN        the q3gltf binary to test (default: <repo>/target/release/q3gltf).
                    The tests never build it; a missing binary is a failure, not a skip.
  Q3GLTF_DATA       cache dir for the OpenArena game data, handed to
                    samples/fetch-openarena.sh (default: ~/.cache/q3gltf/openarena).
  Q3GLTF_EXTRACTED  where the .bsp files are unpacked from their pk3 (default:
                    ~/.cache/q3gltf/extracted, or "$Q3GLTF_DATA-extracted" beside
                    Q3GLTF_DATA when that is set).

Any test that takes the ``bsp_map`` fixture runs once per map of MAP_PAKS, with ids
like ``pak1/oa_dm1`` and ``patch088/aggressor``.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import os
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
FETCH_SCRIPT = REPO_ROOT / "samples" / "fetch-openarena.sh"
NODE_DIR = REPO_ROOT / "tests" / "node"
DEFAULT_BIN = REPO_ROOT / "target" / "release" / "q3gltf"

# Short label (used in test ids) -> pk3 file in baseoa holding the maps under maps/*.bsp.
MAP_PAKS = {
    "pak1": "pak1-maps.pk3",          # OpenArena 0.8.1 maps (50)
    "patch088": "pak6-patch088.pk3",  # OpenArena 0.8.8 patch maps (38)
}


# --------------------------------------------------------------------------- data paths

@functools.lru_cache(maxsize=None)
def baseoa_dir() -> Path:
    """Run samples/fetch-openarena.sh (cheap when cached) and return the baseoa dir."""
    try:
        proc = subprocess.run(["bash", str(FETCH_SCRIPT)], capture_output=True, text=True,
                              timeout=1800, check=False)
    except subprocess.TimeoutExpired as exc:  # pragma: no cover - network trouble
        raise RuntimeError(f"{FETCH_SCRIPT} timed out") from exc
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        raise RuntimeError(
            f"{FETCH_SCRIPT} failed (exit {proc.returncode}):\n{proc.stderr.strip()}")
    path = Path(lines[-1])
    if not path.is_dir():
        raise RuntimeError(f"{FETCH_SCRIPT} printed {path}, which is not a directory")
    return path


def extracted_root() -> Path:
    if os.environ.get("Q3GLTF_EXTRACTED"):
        return Path(os.environ["Q3GLTF_EXTRACTED"]).expanduser()
    if os.environ.get("Q3GLTF_DATA"):
        data = Path(os.environ["Q3GLTF_DATA"]).expanduser().resolve()
        return data.with_name(data.name + "-extracted")
    return Path.home() / ".cache" / "q3gltf" / "extracted"


def _bsp_members(zf: zipfile.ZipFile) -> list[zipfile.ZipInfo]:
    """maps/*.bsp entries (top level of maps/ only), as the game itself finds them."""
    out = []
    for info in zf.infolist():
        name = info.filename
        if info.is_dir() or not name.lower().startswith("maps/") or not name.lower().endswith(".bsp"):
            continue
        if "/" in name[len("maps/"):]:
            continue
        out.append(info)
    return sorted(out, key=lambda i: i.filename.lower())


@functools.lru_cache(maxsize=None)
def list_maps(pk3_name: str) -> tuple[str, ...]:
    """Map names (no extension) inside baseoa/<pk3_name>, sorted; reads only the zip index."""
    with zipfile.ZipFile(baseoa_dir() / pk3_name) as zf:
        return tuple(Path(i.filename).stem for i in _bsp_members(zf))


@functools.lru_cache(maxsize=None)
def extract_maps(pk3_name: str) -> tuple[Path, ...]:
    """Unpack the .bsp files of baseoa/<pk3_name> into <extracted_root>/<pk3 stem>/maps/.

    A stamp file (pk3 size, mtime and member sizes/CRCs) makes later calls a no-op; each
    file is written to a temporary name and renamed, so an interrupted run leaves no
    half-written .bsp behind. Returns the sorted .bsp paths.
    """
    pk3 = baseoa_dir() / pk3_name
    dest = extracted_root() / Path(pk3_name).stem / "maps"
    dest.mkdir(parents=True, exist_ok=True)
    st = pk3.stat()
    with zipfile.ZipFile(pk3) as zf:
        members = _bsp_members(zf)
        stamp = json.dumps({
            "pk3": str(pk3), "size": st.st_size, "mtime_ns": st.st_mtime_ns,
            "members": [[m.filename, m.file_size, m.CRC] for m in members],
        }, sort_keys=True)
        stamp_file = dest / ".extracted.json"
        paths = [dest / Path(m.filename).name for m in members]
        up_to_date = (stamp_file.is_file() and stamp_file.read_text() == stamp
                      and all(p.is_file() and p.stat().st_size == m.file_size
                              for p, m in zip(paths, members)))
        if not up_to_date:
            for m, p in zip(members, paths):
                fd, tmp = tempfile.mkstemp(dir=dest, prefix=".tmp-", suffix=".bsp")
                try:
                    with os.fdopen(fd, "wb") as out, zf.open(m) as src:
                        shutil.copyfileobj(src, out, 1 << 20)
                    os.replace(tmp, p)
                except BaseException:
                    Path(tmp).unlink(missing_ok=True)
                    raise
            stamp_file.write_text(stamp)
    return tuple(sorted(paths))


# --------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="session")
def q3gltf() -> Path:
    """Path of the q3gltf binary under test ($Q3GLTF_BIN or target/release/q3gltf)."""
    path = Path(os.environ.get("Q3GLTF_BIN") or DEFAULT_BIN)
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(
            f"q3gltf binary not found or not executable: {path}\n"
            "Build it first (cargo build --release) or point Q3GLTF_BIN at it; "
            "these tests never build it.", pytrace=False)
    return path


@pytest.fixture(scope="session")
def baseoa() -> Path:
    """The OpenArena baseoa directory (holds the pk3 files), from fetch-openarena.sh."""
    try:
        return baseoa_dir()
    except RuntimeError as exc:
        pytest.fail(str(exc), pytrace=False)


@pytest.fixture(scope="session")
def extracted_maps(baseoa):
    """A function pk3_name -> sorted list of extracted .bsp paths (cached on disk)."""
    def get(pk3_name: str) -> list[Path]:
        return list(extract_maps(pk3_name))
    return get


@pytest.fixture(scope="session")
def node_validator() -> Path:
    """tests/node/validate.mjs, after checking that node and its dependency are there."""
    script = NODE_DIR / "validate.mjs"
    if shutil.which("node") is None:
        pytest.fail("node is not on PATH (needed for the glTF validator)", pytrace=False)
    if not (NODE_DIR / "node_modules" / "gltf-validator").is_dir():
        pytest.fail(f"gltf-validator is not installed: run `npm ci` in {NODE_DIR}", pytrace=False)
    return script


@dataclasses.dataclass(frozen=True)
class BspMap:
    pak: str      # label from MAP_PAKS, e.g. "pak1"
    pk3: str      # pk3 file name, e.g. "pak1-maps.pk3"
    name: str     # map name without extension, e.g. "oa_dm1"
    path: Path | None = None  # the extracted .bsp (set by the bsp_map fixture)

    @property
    def id(self) -> str:
        return f"{self.pak}/{self.name}"


def all_map_cases() -> list[BspMap]:
    return [BspMap(pak, pk3, name) for pak, pk3 in MAP_PAKS.items() for name in list_maps(pk3)]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "bsp_map" in metafunc.fixturenames:
        cases = all_map_cases()
        metafunc.parametrize("bsp_map", cases, ids=[c.id for c in cases], indirect=True)


@pytest.fixture
def bsp_map(request, extracted_maps) -> BspMap:
    """One map of MAP_PAKS (parametrised), with .path pointing at its extracted .bsp."""
    case: BspMap = request.param
    by_stem = {p.stem: p for p in extracted_maps(case.pk3)}
    return dataclasses.replace(case, path=by_stem[case.name])


def selected_map_cases(request: pytest.FixtureRequest, module_only: bool = True) -> list[BspMap]:
    """The bsp_map parameters of the tests actually selected in this session (after -k and
    deselection), restricted to the requesting module by default. Lets a module-scoped
    fixture do batch work only for the maps that will be looked at."""
    seen: dict[str, BspMap] = {}
    for item in request.session.items:
        if module_only and item.module is not request.module:
            continue
        callspec = getattr(item, "callspec", None)
        if callspec is not None and "bsp_map" in callspec.params:
            case = callspec.params["bsp_map"]
            seen.setdefault(case.id, case)
    return list(seen.values())
