#!/usr/bin/env bash
# `make render`: relit maps in Blender beside the game's own frames.
#
# For each map of RENDER_MAPS (default: oa_dm1 and two of the fidelity truth set,
# oacmpdm4 and oacmpctf1): convert it, relight it twice (`--look lightmap`, the default,
# and `--look game`), take the game's frames from its first three spawn points
# (tools/game/frame.py: OpenArena on ioquake3 under Xvfb), render the same views in
# Blender (tools/blender/render.py --poses: the relit files, and the baked lighting as
# the engine draws it, the floor), and compare them in linear light
# (tools/game/compare.py): OUT/render/table.{md,csv} and OUT/render/side_by_side/*.png.
#
# Environment (the Makefile sets them): BIN, OUT, VENV, BLENDER_VENV, RELIGHT_FLAGS,
# RENDER_MAPS, RENDER_SPAWNS (3), RENDER_SAMPLES (32), GAME_DIR.
set -euo pipefail
BIN="${BIN:-target/release/q3gltf}"
OUT="${OUT:-out}"
VENV="${VENV:-.venv}"
BLENDER_VENV="${BLENDER_VENV:-.venv-blender}"
MAPS="${RENDER_MAPS:-oa_dm1 oacmpdm4 oacmpctf1}"
SPAWNS="${RENDER_SPAWNS:-3}"
SAMPLES="${RENDER_SAMPLES:-32}"
RELIGHT_FLAGS="${RELIGHT_FLAGS:-}"
fetch=samples/fetch-openarena.sh
baseoa="${GAME_DIR:-$(bash "$fetch")}"
engine="$(bash "$fetch" --engine)"
oacmp="$(bash "$fetch" --oacmp)"
dirs=()
for m in $MAPS; do
  d="$OUT/render/$m"
  mkdir -p "$d"
  extra=()
  case "$m" in oacmp*) extra=(--game-dir "$oacmp") ;; esac
  echo "== $m: convert, relight (look lightmap, look game)" >&2
  "$BIN" convert "$m" --game-dir "$baseoa" "${extra[@]}" -q -o "$d/$m.gltf"
  # shellcheck disable=SC2086
  "$BIN" relight "$d/$m.gltf" -o "$d/$m.relit.gltf" -q --report "$d/$m.report.json" $RELIGHT_FLAGS
  # shellcheck disable=SC2086
  "$BIN" relight "$d/$m.gltf" -o "$d/$m.game.gltf" -q --report "$d/$m.game.report.json" --look game $RELIGHT_FLAGS
  echo "== $m: the game's frames" >&2
  "$VENV/bin/python" tools/game/frame.py --engine "$engine" --map "$m" --gltf "$d/$m.gltf" --spawns "$SPAWNS" --out "$d"
  echo "== $m: Blender" >&2
  "$BLENDER_VENV/bin/python" tools/blender/render.py --relit "$d/$m.relit.gltf" --original "$d/$m.gltf" \
    --also "relit-game=$d/$m.game.gltf" --poses "$d/poses.json" --out "$d" --samples "$SAMPLES" > /dev/null
  dirs+=("$d")
done
"$VENV/bin/python" tools/game/compare.py --views "${dirs[@]}" --table "$OUT/render/table" --side-by-side "$OUT/render/side_by_side"
