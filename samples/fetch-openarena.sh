#!/usr/bin/env bash
# Fetch the OpenArena game data (GPL) from Debian's packages into a cache directory.
#
# Usage: samples/fetch-openarena.sh [--oacmp] [CACHE_DIR]
#   CACHE_DIR defaults to $Q3GLTF_DATA, else ~/.cache/q3gltf/openarena.
# Prints the path of the `baseoa` directory (the game dir holding the .pk3 files).
# With --oacmp: also fetches the OpenArena community map pack vol. 1
# (`openarena-oacmp1`, whose pk3 ships the maps' .map sources: the fidelity truth set)
# into its own folder, so that it never shadows the game's shaders, and prints that
# folder instead (use it as a second --game-dir after baseoa).
#
# The download is skipped when the cache already holds every pk3 we use, so this is
# cheap to call before every test run. No root needed: `apt-get download` + `dpkg -x`.
set -euo pipefail
oacmp=0
if [ "${1:-}" = --oacmp ]; then oacmp=1; shift; fi
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
  echo "$dir"
else
  echo "$baseoa"
fi
