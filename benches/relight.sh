#!/usr/bin/env bash
# Relight benchmark: speed against error on the bundled sample and on oa_dm1, for each
# backend, in one run (compare ratios, not absolute times). Prints and saves a Markdown
# table to out/bench/relight.md. Usage: benches/relight.sh BIN GAME_DIR
set -euo pipefail
bin=$1; game=$2; out=out/bench; mkdir -p "$out/relight"
"$bin" convert samples/sample/maps/sample.bsp -q -o "$out/relight/sample.glb"
"$bin" convert oa_dm1 --game-dir "$game" -q -o "$out/relight/oa_dm1.glb"
table="$out/relight.md"
{
  echo "| scene | backend | vertices | lights | rel. error | total s | target s | init s | optimise s | rays |"
  echo "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
} > "$table"
for scene in sample oa_dm1; do
  for backend in cpu wgpu; do
    rep="$out/relight/$scene.$backend.json"
    if ! "$bin" relight "$out/relight/$scene.glb" -o "$out/relight/$scene.$backend.relit.glb" --backend "$backend" -q --report "$rep" > /dev/null 2>&1; then
      echo "| $scene | $backend | (failed: no adapter?) | | | | | | | |" >> "$table"; continue
    fi
    python3 - "$rep" "$scene" >> "$table" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); st = dict(r["stage_times_s"])
print(f"| {sys.argv[2]} | {r['backend']} | {r['problem_vertices']} | {len(r['lights'])} | {r['rel_error_final']:.4f} "
      f"| {r['total_time_s']:.2f} | {st.get('target', 0):.2f} | {st.get('init', 0):.2f} | {st.get('optimise', 0):.2f} | {r['rays_traced']} |")
PY
  done
done
cat "$table"
