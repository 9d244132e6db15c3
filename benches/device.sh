#!/usr/bin/env bash
# The GPU figures of issues 13 and 14 in one call of the `device` tool: relight's wall time
# and stage times on the truth set's maps, on both backends, one after the other on the
# same machine (compare within this table, never across machines). Usage:
#
#   benches/device.sh BIN MAPS OUT [RUN...]
#
# BIN: a `q3gltf` built here (strip it to carry it); MAPS: a folder with the converted
# maps (oa_dm1.glb, oacmpdm3src.glb, oacmpdm4src.glb, oacmpctf1src.glb: `q3gltf convert`
# of oa_dm1 and of the community pack's maps with `--game-dir` for both packs); OUT: where
# the table (device.md), the log and the reports (reports.tgz) go. RUN: labels of the runs
# below to do (all by default). Each run has a time limit of its own, so a slow one
# leaves the others their time; the runs come in the order of what the issues ask first.
#
# Where MAPS also holds `relight-tests` (the relight crate's unit-test binary, stripped:
# `cargo test --release -p q3gltf-relight --lib --no-run` names it), its GPU tests run
# first: every kernel against its CPU reference on the real device, their summary at the
# head of device.md (so far they have run on lavapipe only).
set -uo pipefail
bin=$1; maps=$2; out=$3; shift 3
mkdir -p "$out/reports"
if [ -x "$maps/relight-tests" ]; then
  timeout 180 "$maps/relight-tests" gpu:: > "$out/gpu-tests.log" 2>&1
  echo "GPU kernels against their CPU references on this device (\`$maps/relight-tests gpu::\`): rc $?, $(grep -E '^test result' "$out/gpu-tests.log" | tail -1)" > "$out/gpu-tests.md"
  grep -E '^test .* FAILED$' "$out/gpu-tests.log" | sed 's/^/    /' >> "$out/gpu-tests.md"
  grep -E -A3 'panicked at' "$out/gpu-tests.log" | grep -v -E '^ +[0-9]+: |^stack backtrace|^note: |^--$' | head -40 | sed 's/^/    /' >> "$out/gpu-tests.md"
fi
# label | map | backend | arguments
runs='oa_dm1.wgpu.open|oa_dm1.glb|wgpu|
oa_dm1.wgpu|oa_dm1.glb|wgpu|
oa_dm1.cpu|oa_dm1.glb|cpu|
dm3in.wgpu|oacmpdm3src.glb|wgpu|--init input
dm3in.cpu|oacmpdm3src.glb|cpu|--init input
grid9.wgpu|oa_dm1.glb|wgpu|--init grid:9 --scheme thesis1
oacmpdm4.wgpu|oacmpdm4src.glb|wgpu|
oacmpdm4.cpu|oacmpdm4src.glb|cpu|
oacmpctf1.wgpu|oacmpctf1src.glb|wgpu|
oacmpctf1.cpu|oacmpctf1src.glb|cpu|'
log="$out/device.log"
: > "$log"
echo "$runs" | while IFS='|' read -r label map backend args; do
  if [ $# -gt 0 ] && ! printf '%s\n' "$@" | grep -qx "$label"; then continue; fi
  [ -f "$maps/$map" ] || { echo "$label: no $maps/$map" >> "$log"; continue; }
  start=$(date +%s.%N)
  # shellcheck disable=SC2086 # the arguments are words
  timeout 150 "$bin" relight "$maps/$map" -o "/tmp/device.$label.glb" --backend "$backend" $args -q --report "$out/reports/$label.json" > /dev/null 2>> "$log"
  rc=$?
  echo "$label: rc $rc, wall $(awk "BEGIN { print $(date +%s.%N) - $start }") s" >> "$log"
done
{ [ -f "$out/gpu-tests.md" ] && { cat "$out/gpu-tests.md"; echo; }; python3 "$(dirname "$0")/device_table.py" "$out/reports"; } > "$out/device.md" 2>> "$log"
tar czf "$out/reports.tgz" -C "$out" reports
rm -rf "$out/reports"
cat "$out/device.md" "$log"
