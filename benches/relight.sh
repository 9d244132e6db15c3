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
  echo "| scene | target | backend | rows | lights | rel. error | total s | rows s | init s | optimise s | rays |"
  echo "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
} > "$table"
# The default luxel target on both backends, and the thesis's vertex target (lightmap
# resolution subdivision) on the CPU.
for scene in sample oa_dm1; do
  for run in luxel:cpu luxel:wgpu vertex:cpu; do
    target=${run%%:*}; backend=${run##*:}
    rep="$out/relight/$scene.$target.$backend.json"
    if ! "$bin" relight "$out/relight/$scene.glb" -o "$out/relight/$scene.$target.$backend.relit.glb" --target "$target" --backend "$backend" -q --report "$rep" > /dev/null 2>&1; then
      echo "| $scene | $target | $backend | (failed: no adapter?) | | | | | | | |" >> "$table"; continue
    fi
    python3 - "$rep" "$scene" >> "$table" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); st = dict(r["stage_times_s"])
print(f"| {sys.argv[2]} | {r['target_space']} | {r['backend']} | {r['problem_rows']} | {len(r['lights'])} | {r['rel_error_final']:.4f} "
      f"| {r['total_time_s']:.2f} | {st.get('rows', 0):.2f} | {sum(t for n, t in st.items() if n == 'init' or n.startswith('init:')):.2f} | {st.get('optimise', 0):.2f} | {r['rays_traced']} |")
PY
  done
done
cat "$table"
