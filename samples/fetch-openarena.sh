#!/usr/bin/env bash
# Fetch the OpenArena game data (GPL) from Debian's packages into a cache directory.
#
# Usage: samples/fetch-openarena.sh [CACHE_DIR]
#   CACHE_DIR defaults to $Q3GLTF_DATA, else ~/.cache/q3gltf/openarena.
# Prints the path of the `baseoa` directory (the game dir holding the .pk3 files).
#
# The download is skipped when the cache already holds every pk3 we use, so this is
# cheap to call before every test run. No root needed: `apt-get download` + `dpkg -x`.
set -euo pipefail
cache="${1:-${Q3GLTF_DATA:-$HOME/.cache/q3gltf/openarena}}"
baseoa="$cache/usr/share/games/openarena/baseoa"
want=(pak0.pk3 pak1-maps.pk3 pak4-textures.pk3 pak6-patch085.pk3 pak6-patch088.pk3)
have_all() {
  for f in "${want[@]}"; do [ -s "$baseoa/$f" ] || return 1; done
}
if ! have_all; then
  mkdir -p "$cache/debs"
  (
    cd "$cache/debs"
    pkgs=(openarena-081-maps openarena-081-textures openarena-data openarena-085-data openarena-088-data)
    if ! apt-get download "${pkgs[@]}" >&2; then
      # Package lists may be missing on a fresh machine; refreshing them needs root.
      if [ "$(id -u)" = 0 ]; then apt-get update -qq >&2 && apt-get download "${pkgs[@]}" >&2
      else echo "fetch-openarena: apt-get download failed (run 'sudo apt-get update' first)" >&2; exit 1; fi
    fi
  )
  for deb in "$cache"/debs/*.deb; do dpkg -x "$deb" "$cache"; done
  rm -rf "$cache/debs"
  have_all || { echo "fetch-openarena: pk3 files missing after extraction in $baseoa" >&2; exit 1; }
fi
echo "$baseoa"
