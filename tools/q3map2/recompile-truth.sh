#!/usr/bin/env bash
# Recompiles truth-set maps with q3map2 and measures relight's fidelity on them
# (maintainers only; the recompiles are game data and are never committed).
#
# Usage: tools/q3map2/recompile-truth.sh Q3MAP2 [MAP...]
#   Q3MAP2: a q3map2 binary (netradiant-custom at 68c604d2; tests/fixtures/q3map2/README.md
#   says how to build it). MAPs default to the truth set: oacmpdm1-4 and oacmpctf1.
#   LIGHT="..." in the environment replaces the light switches (default: point lights
#   only, `-fast -patchshadows -areascale 0 -skyscale 0`).
#   KEEP=1 keeps the work folder (the BSPs, q3map2's logs, the GLBs and reports).
#
# Each map's `.map` source (from the OACMP pk3) is compiled `-meta`, lit with the
# switches, converted with `--lights-from` its source, and relit from its own lights with
# only the global terms fitted (`--init input --fit globals`): the figure is how far the
# model is from what q3map2 made of the map's true lights.
#
# q3map2 reads shader scripts only through `scripts/shaderlist.txt`; without one listing
# every script of the game, it compiles with default shaders (no surface parameters), and
# the lightmaps no longer match the shaders relight reads. This script writes that list.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$here/../.."
q3map2="$(realpath "$1")"; shift
light="${LIGHT:--fast -patchshadows -areascale 0 -skyscale 0}"
baseoa="$(bash "$root/samples/fetch-openarena.sh")"
oacmp="$(bash "$root/samples/fetch-openarena.sh" --oacmp)"
q3gltf="${Q3GLTF:-$root/target/release/q3gltf}"
[ -x "$q3gltf" ] || { echo "recompile-truth: build q3gltf first (cargo build --release)" >&2; exit 1; }
work="$(mktemp -d)"
trap 'if [ -n "${KEEP:-}" ]; then echo "kept $work"; else rm -rf "$work"; fi' EXIT
mkdir -p "$work/baseoa/maps" "$work/baseoa/scripts"
for pk3 in "$baseoa"/*.pk3 "$oacmp"/*.pk3; do ln -s "$pk3" "$work/baseoa/"; done
# Every script of every pk3, by name (the list q3map2 reads).
for pk3 in "$baseoa"/*.pk3 "$oacmp"/*.pk3; do
  python3 -c 'import sys, zipfile; [print(n[8:-7]) for n in zipfile.ZipFile(sys.argv[1]).namelist() if n.startswith("scripts/") and n.endswith(".shader")]' "$pk3"
done | sort -u > "$work/baseoa/scripts/shaderlist.txt"
maps=("$@")
[ ${#maps[@]} -gt 0 ] || maps=(oacmpdm1 oacmpdm2 oacmpdm3 oacmpdm4 oacmpctf1)
printf '%-10s %10s  %s\n' map rel_error "largest residual (material: share)"
for m in "${maps[@]}"; do
  src="$work/baseoa/maps/$m.map"
  python3 -c 'import sys, zipfile; sys.stdout.buffer.write(zipfile.ZipFile(sys.argv[1]).read("sources/maps/" + sys.argv[2] + ".map"))' "$oacmp/z_oacmp-volume1-v3.pk3" "$m" > "$src"
  args=(-game quake3 -fs_basepath "$work" -fs_game baseoa)
  "$q3map2" "${args[@]}" -meta "$src" > "$work/$m.bsp.log" 2>&1 || { tail "$work/$m.bsp.log"; exit 1; }
  # shellcheck disable=SC2086
  "$q3map2" "${args[@]}" -light $light "$work/baseoa/maps/$m.bsp" > "$work/$m.light.log" 2>&1 || { tail "$work/$m.light.log"; exit 1; }
  "$q3gltf" convert "$work/baseoa/maps/$m.bsp" --game-dir "$baseoa" --game-dir "$oacmp" --lights-from "$src" -o "$work/$m.glb" -q > /dev/null
  "$q3gltf" relight "$work/$m.glb" -o "$work/$m.fit.glb" --init input --fit globals --backend cpu --report "$work/$m.json" -q > /dev/null
  python3 -c '
import json, sys
r = json.load(open(sys.argv[1]))
top = ", ".join("%s: %.2f" % (g["material"].split("/")[-1], g["residual_share"]) for g in r["residual_by_material"][:3])
print("%-10s %10.4f  %s" % (sys.argv[2], r["rel_error_final"], top))' "$work/$m.json" "$m"
done
