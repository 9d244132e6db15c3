#!/usr/bin/env bash
# Builds the fuzz targets and runs each for FUZZ_SECONDS (default 60) on its corpus
# (fuzz/corpus/<target>, grown between runs) plus the seeds made by fuzz/seed.sh.
# Prefers a nightly toolchain; on stable it sets RUSTC_BOOTSTRAP=1 (what cargo-fuzz's
# -Z flags need) and falls back to no sanitizer if AddressSanitizer cannot be built.
# Installs cargo-fuzz when missing. Writes a table of runs and executions to
# fuzz/artifacts/summary.md; exits non-zero if any target crashed (the input is kept in
# fuzz/artifacts/<target>/).
#
#   bash fuzz/run.sh [TARGET...]        FUZZ_SECONDS=N  FUZZ_JOBS=N (default 1)
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH=${FUZZ_SECONDS:-60}
TARGETS=("$@")
[ ${#TARGETS[@]} -gt 0 ] || TARGETS=(bsp shader pk3 texture gltf_in baked_gltf)

command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
if rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
  FUZZ=(cargo +nightly fuzz)
  toolchain=nightly
else
  export RUSTC_BOOTSTRAP=1
  FUZZ=(cargo fuzz)
  toolchain="stable + RUSTC_BOOTSTRAP=1"
fi
# One build of every target, then the binaries are run directly (no rebuild per target).
sanitizer=address
if ! (cd fuzz && "${FUZZ[@]}" build -s address); then
  echo "fuzz: AddressSanitizer build failed; building without a sanitizer" >&2
  sanitizer=none
  (cd fuzz && "${FUZZ[@]}" build -s none)
fi
triple=$(rustc -vV | sed -n 's/^host: //p')
bindir="fuzz/target/$triple/release"

bash fuzz/seed.sh
mkdir -p fuzz/artifacts
summary=fuzz/artifacts/summary.md
{
  echo "| target | seconds | executions | corpus inputs | result |"
  echo "|---|---|---|---|---|"
} > "$summary"
failed=0
npass=0
nfail=0
for t in "${TARGETS[@]}"; do
  mkdir -p "fuzz/corpus/$t" "fuzz/artifacts/$t"
  log="fuzz/artifacts/$t.log"
  echo "fuzz: $t for ${SECONDS_EACH}s ($toolchain, sanitizer $sanitizer)"
  set +e
  # -rss_limit_mb: an input that makes a parser allocate past 2 GiB is a failure too.
  # xatlas (vendored by xatlas-rs 0.1.3) leaks an index array per chart (its Array's
  # assignment is a shallow copy): leak checks off for the target that runs it; ASan still
  # reports every invalid access or double free.
  extra=(); asan=${ASAN_OPTIONS:-}
  [ "$t" = baked_gltf ] && { extra=(-detect_leaks=0); asan=${asan:+$asan:}detect_leaks=0; }
  (cd fuzz && ASAN_OPTIONS=$asan "../$bindir/$t" "corpus/$t" "seeds/$t" "${extra[@]}" \
      -max_total_time="$SECONDS_EACH" -timeout=20 -rss_limit_mb=2048 -print_final_stats=1 \
      -artifact_prefix="artifacts/$t/") > "$log" 2>&1
  rc=$?
  set -e
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  inputs=$(ls "fuzz/corpus/$t" | wc -l)
  if [ $rc -eq 0 ]; then
    result=ok; npass=$((npass + 1))
  else
    result="CRASH (rc $rc, see fuzz/artifacts/$t/ and $log)"; failed=1; nfail=$((nfail + 1))
  fi
  echo "| $t | $SECONDS_EACH | ${execs:-?} | $inputs | $result |" >> "$summary"
  tail -n 3 "$log"
done
cat "$summary"
if [ $failed -ne 0 ]; then
  grep -h -B2 -A25 -E 'panicked|ERROR: libFuzzer|deadly signal|SUMMARY' fuzz/artifacts/*.log | head -150 >&2 || true
fi
echo "fuzz: $npass passed, $nfail failed"
exit $failed
