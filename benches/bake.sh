#!/usr/bin/env bash
# Bake benchmark: `q3gltf bake` of relit scenes at their original lightmap density, on
# each backend, in one run (compare ratios, not absolute times). Needs the relit scenes
# of benches/relight.sh (run it first). Prints and saves out/bench/bake.md.
# Usage: benches/bake.sh BIN
set -euo pipefail
bin=$1; out=out/bench; mkdir -p "$out/bake"
table="$out/bake.md"
{
  echo "| scene | backend | texels | lights | bounces | rel. error | total s | render s |"
  echo "|---|---|---:|---:|---:|---:|---:|---:|"
} > "$table"
for scene in sample oa_dm1; do
  in="$out/relight/$scene.luxel.cpu.relit.glb"
  [ -f "$in" ] || { echo "| $scene | (no relit scene: run benches/relight.sh) | | | | | | |" >> "$table"; continue; }
  for backend in cpu wgpu; do
    dir="$out/bake/$scene.$backend"
    if ! "$bin" bake "$in" -o "$dir" --backend "$backend" -q > /dev/null 2>&1; then
      echo "| $scene | $backend | (failed: no adapter?) | | | | | |" >> "$table"; continue
    fi
    python3 - "$dir/bake.json" "$scene" >> "$table" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); st = dict(r["stages"])
print(f"| {sys.argv[2]} | {r['backend']} | {r['luxels']} | {r['lights']} | {r['bounces']} | {r['rel_error']:.4f} | {r['seconds']:.2f} | {st.get('render', 0):.2f} |")
PY
  done
done
cat "$table"
