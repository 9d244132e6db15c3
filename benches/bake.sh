#!/usr/bin/env bash
# Bake benchmark: `q3gltf bake` of relit scenes in their own lightmap layout, and charted
# anew (`--new-uvs`, xatlas) at the original texel size, half of it (4x the texels) and a
# quarter of it (16x), on each backend, in one run (compare ratios, not absolute times).
# Needs the relit scenes of benches/relight.sh (run it first). Prints and saves
# out/bench/bake.md.
# Usage: benches/bake.sh BIN
set -euo pipefail
bin=$1; out=out/bench; mkdir -p "$out/bake"
table="$out/bake.md"
{
  echo "| scene | layout | backend | texels | lights | bounces | rel. error | total s | atlas s | render s |"
  echo "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"
} > "$table"
for scene in sample oa_dm1; do
  in="$out/relight/$scene.luxel.cpu.relit.glb"
  [ -f "$in" ] || { echo "| $scene | (no relit scene: run benches/relight.sh) | | | | | | | | |" >> "$table"; continue; }
  # The scene's own texel size, from a bake in its own layout (bake.json of --new-uvs).
  "$bin" bake "$in" -o "$out/bake/$scene.texel" --new-uvs --backend cpu --bounces 0 --no-previews -q > /dev/null
  texel=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['atlas']['texel_m'])" "$out/bake/$scene.texel/bake.json")
  for layout in own new:1 new:2 new:4; do
    case $layout in
      own) flags=(); name="own" ;;
      new:*) f=${layout#new:}; flags=(--new-uvs --texel-size "$(python3 -c "print($texel / $f)")"); name="new, texel / $f" ;;
    esac
    for backend in cpu wgpu; do
      dir="$out/bake/$scene.${layout/:/}.$backend"
      if ! "$bin" bake "$in" -o "$dir" --backend "$backend" "${flags[@]}" -q > /dev/null 2>&1; then
        echo "| $scene | $name | $backend | (failed: no adapter?) | | | | | | |" >> "$table"; continue
      fi
      python3 - "$dir/bake.json" "$scene" "$name" >> "$table" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); st = dict(r["stages"])
err = f"{r['rel_error']:.4f}" if r.get("rel_error") is not None else "(new)"
print(f"| {sys.argv[2]} | {sys.argv[3]} | {r['backend']} | {r['luxels']} | {r['lights']} | {r['bounces']} | {err} | {r['seconds']:.2f} | {st.get('atlas', 0):.2f} | {st.get('render', 0):.2f} |")
PY
    done
  done
done
cat "$table"
