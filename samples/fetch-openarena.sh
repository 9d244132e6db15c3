#!/usr/bin/env bash
# Fetch the OpenArena game data (GPL) from Debian's packages into a cache directory.
#
# Usage: samples/fetch-openarena.sh [--oacmp | --engine] [CACHE_DIR]
#   CACHE_DIR defaults to $Q3GLTF_DATA, else ~/.cache/q3gltf/openarena.
# Prints the path of the `baseoa` directory (the game dir holding the .pk3 files).
# With --oacmp: also fetches the OpenArena community map pack vol. 1
# (`openarena-oacmp1`, whose pk3 ships the maps' .map sources: the fidelity truth set)
# into its own folder, so that it never shadows the game's shaders, and prints that
# folder instead (use it as a second --game-dir after baseoa).
# With --engine: also fetches what the game itself needs to run on Debian's `ioquake3`
# engine (package `openarena`: the native game modules; `openarena-081-players` and
# `-misc`: player models and menus the game loads) into `CACHE_DIR/engine`, links the map
# and texture pk3s (and the OACMP pack) into it, and prints the engine's `fs_basepath`.
# Only tools/game/frame.py (the game's own frames, a test and bench reference) uses it;
# the engine binary comes from `apt-get install ioquake3`.
#
# The download is skipped when the cache already holds every pk3 we use, so this is
# cheap to call before every test run. No root needed: `apt-get download` + `dpkg -x`.
set -euo pipefail
oacmp=0; engine=0
if [ "${1:-}" = --oacmp ]; then oacmp=1; shift; fi
if [ "${1:-}" = --engine ]; then engine=1; oacmp=1; shift; fi
cache="${1:-${Q3GLTF_DATA:-$HOME/.cache/q3gltf/openarena}}"
baseoa="$cache/usr/share/games/openarena/baseoa"
want=(pak0.pk3 pak1-maps.pk3 pak4-textures.pk3 pak6-patch085.pk3 pak6-patch088.pk3)
have_all() {
  for f in "${want[@]}"; do [ -s "$baseoa/$f" ] || return 1; done
}
# fetch DEST PACKAGE...: downloads the Debian packages and extracts them under DEST.
fetch() {
  local dest="$1"; shift
  mkdir -p "$dest/debs"
  (
    cd "$dest/debs"
    if ! apt-get download "$@" >&2; then
      # Package lists may be missing on a fresh machine; refreshing them needs root.
      if [ "$(id -u)" = 0 ]; then apt-get update -qq >&2 && apt-get download "$@" >&2
      else echo "fetch-openarena: apt-get download failed (run 'sudo apt-get update' first)" >&2; exit 1; fi
    fi
  )
  for deb in "$dest"/debs/*.deb; do dpkg -x "$deb" "$dest"; done
  rm -rf "$dest/debs"
}
if ! have_all; then
  fetch "$cache" openarena-081-maps openarena-081-textures openarena-data openarena-085-data openarena-088-data
  have_all || { echo "fetch-openarena: pk3 files missing after extraction in $baseoa" >&2; exit 1; }
fi
if [ "$oacmp" = 1 ]; then
  dir="$cache/oacmp1/usr/share/games/openarena/baseoa"
  if [ ! -s "$dir/z_oacmp-volume1-v3.pk3" ]; then
    fetch "$cache/oacmp1" openarena-oacmp1
    [ -s "$dir/z_oacmp-volume1-v3.pk3" ] || { echo "fetch-openarena: z_oacmp-volume1-v3.pk3 missing after extraction in $dir" >&2; exit 1; }
  fi
fi
if [ "$engine" = 1 ]; then
  # The package's own layout: /usr/lib/openarena/baseoa holds the game modules (one folder
  # per pk3 whose stub .qvm they replace) and links ../../../share/games/openarena/baseoa/*.pk3.
  root="$cache/engine"
  game="$root/usr/lib/openarena/baseoa"
  if [ ! -s "$game/pak6-patch088/qagamex86_64.so" ] || [ ! -s "$root/usr/share/games/openarena/baseoa/pak2-players.pk3" ]; then
    fetch "$root" openarena openarena-081-players openarena-081-misc
  fi
  for f in "${want[@]}"; do ln -sfn "$baseoa/$f" "$root/usr/share/games/openarena/baseoa/$f"; done
  ln -sfn "$dir/z_oacmp-volume1-v3.pk3" "$game/z_oacmp-volume1-v3.pk3"
  # Links to packages we do not fetch would only make the engine print warnings.
  for l in "$game"/*.pk3; do [ -e "$l" ] || rm -f "$l"; done
  [ -s "$game/pak2-players.pk3" ] && [ -s "$game/pak0.pk3" ] || { echo "fetch-openarena: engine folder incomplete in $game" >&2; exit 1; }
  echo "$root/usr/lib/openarena"
elif [ "$oacmp" = 1 ]; then
  echo "$dir"
else
  echo "$baseoa"
fi
