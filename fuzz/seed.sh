#!/usr/bin/env bash
# Seeds fuzz/seeds/<target>/ for each fuzz target from the bundled sample (ours) and the
# fetched OpenArena data (GPL, never committed): small BSPs cut from real maps, every
# real shader script, small pk3s rebuilt from real entries, small real images, and glTF
# files converted from those. Idempotent: fixed file names, rewritten on each run.
#
#   bash fuzz/seed.sh            (needs target/release/q3gltf: `make build`)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-target/release/q3gltf}
CARGO=${CARGO:-cargo}
S=fuzz/seeds
[ -x "$BIN" ] || { echo "seed.sh: $BIN missing (run 'make build')" >&2; exit 1; }
BASEOA=${BASEOA:-$(bash samples/fetch-openarena.sh)}
$CARGO build --release -q -p q3gltf-convert --example bsp_subset
SUBSET=target/release/examples/bsp_subset
rm -rf "$S"
mkdir -p "$S"/{bsp,shader,pk3,texture,gltf_in,baked_gltf}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# BSP: the sample, and a few surfaces of each type from real maps (IBSP 46, and RBSP 1
# written by our writer).
cp samples/sample/maps/sample.bsp "$S/bsp/sample.bsp"
for spec in pak1-maps.pk3:oa_dm1 pak1-maps.pk3:oa_ctf2 pak1-maps.pk3:oa_dm5 pak1-maps.pk3:oa_dm3 pak6-patch088.pk3:am_lavaarena; do
  pk3=${spec%%:*}; map=${spec#*:}
  unzip -p "$BASEOA/$pk3" "maps/$map.bsp" > "$tmp/$map.bsp"
  "$SUBSET" "$tmp/$map.bsp" "$S/bsp/$map-subset.bsp" 3 >/dev/null
done
"$SUBSET" "$tmp/oa_dm5.bsp" "$S/bsp/oa_dm5-subset-rbsp.bsp" 2 rbsp >/dev/null

# Shader scripts: ours and every script of the game.
cp samples/sample/scripts/sample.shader "$S/shader/"
unzip -q -j -o "$BASEOA/pak0.pk3" 'scripts/*.shader' -d "$S/shader"

# Images: the first byte of a texture input picks the extension (0 tga, 1 jpg, 2 png).
python3 - "$BASEOA" "$S" samples/sample <<'PY'
import os, sys, zipfile
baseoa, seeds, sample = sys.argv[1:4]
pick = {'.tga': b'\0', '.jpg': b'\1', '.png': b'\2'}
def put(name, data, ext):
    with open(os.path.join(seeds, 'texture', name), 'wb') as f:
        f.write(pick[ext] + data)
tex = os.path.join(sample, 'textures', 'sample')
for n in sorted(os.listdir(tex)):
    put('sample-' + n, open(os.path.join(tex, n), 'rb').read(), '.tga')
pak0 = zipfile.ZipFile(os.path.join(baseoa, 'pak0.pk3'))
small = {}
for i in pak0.infolist():
    ext = os.path.splitext(i.filename)[1].lower()
    if ext in pick and 500 < i.file_size <= 16384:
        small.setdefault(ext, []).append(i)
chosen = []
for ext, items in sorted(small.items()):
    items.sort(key=lambda i: (i.file_size, i.filename))
    for i in items[:: max(1, len(items) // 4)][:4]:
        put('oa-' + i.filename.replace('/', '_'), pak0.read(i), ext)
        chosen.append(i)
# pk3: the sample game directory, and one rebuilt from a few real entries (stored and
# deflated, with a directory entry), like the engine's archives.
with zipfile.ZipFile(os.path.join(seeds, 'pk3', 'sample.pk3'), 'w', zipfile.ZIP_DEFLATED) as z:
    for root, _, files in sorted(os.walk(sample)):
        for n in sorted(files):
            p = os.path.join(root, n)
            z.write(p, os.path.relpath(p, sample))
with zipfile.ZipFile(os.path.join(seeds, 'pk3', 'oa-mini.pk3'), 'w') as z:
    z.writestr(zipfile.ZipInfo('textures/'), b'')
    script = min((i for i in pak0.infolist() if i.filename.endswith('.shader')), key=lambda i: i.file_size)
    for k, i in enumerate([script] + chosen[:3]):
        z.writestr(i.filename, pak0.read(i), zipfile.ZIP_DEFLATED if k % 2 == 0 else zipfile.ZIP_STORED)
PY

# glTF: the sample and a real-map cut, as .glb and as .gltf with data URIs.
"$BIN" convert samples/sample/maps/sample.bsp --entity-lights -q -o "$S/gltf_in/sample.glb" >/dev/null
"$BIN" convert "$S/bsp/oa_ctf2-subset.bsp" --game-dir "$BASEOA" -q -o "$tmp/oa_ctf2-subset.glb" >/dev/null
[ "$(stat -c %s "$tmp/oa_ctf2-subset.glb")" -le 262144 ] && cp "$tmp/oa_ctf2-subset.glb" "$S/gltf_in/"
python3 - "$S/gltf_in/sample.glb" "$S/gltf_in/sample-embedded.gltf" <<'PY'
import base64, json, struct, sys
data = open(sys.argv[1], 'rb').read()
jl = struct.unpack_from('<I', data, 12)[0]
doc = json.loads(data[20:20 + jl])
bl = struct.unpack_from('<I', data, 20 + jl)[0]
binary = data[28 + jl:28 + jl + bl]
doc['buffers'][0]['uri'] = 'data:application/octet-stream;base64,' + base64.b64encode(binary).decode()
json.dump(doc, open(sys.argv[2], 'w'))
PY
# The bake's glTF editing reads the same files (and a bake's own output: a new atlas).
cp "$S"/gltf_in/* "$S/baked_gltf/"
"$BIN" bake "$S/gltf_in/sample.glb" -o "$tmp/bake" --new-uvs --backend cpu --no-previews -q >/dev/null
cp "$tmp/bake/baked.glb" "$S/baked_gltf/sample-baked.glb"
for t in bsp shader pk3 texture gltf_in baked_gltf; do
  echo "seeds/$t: $(ls "$S/$t" | wc -l) files, $(du -sk "$S/$t" | cut -f1) KiB"
done
