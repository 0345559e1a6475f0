#!/usr/bin/env bash
# Runs every fuzz target for a short while and fails when one crashes (a panic, an allocation over the
# limits, a timeout). Needs a nightly toolchain; without one it says so and succeeds.
#
#   fuzz/ci.sh                      # each target FUZZ_SECONDS (default 40) seconds
#   FUZZ_SECONDS=600 fuzz/ci.sh     # longer
#   FUZZ_SEED=7 fuzz/ci.sh          # other mutations (default seed 1)
#
# Each target starts from the committed seeds (fuzz/corpus/<target>/) and the regression inputs
# (fuzz/regressions/<target>/); the inputs it finds go to a scratch corpus under fuzz/target/, so the
# committed corpus does not grow. A crash is written to fuzz/artifacts/<target>/ (by cargo-fuzz) and its
# log to fuzz/target/ci-logs/<target>.log.
set -uo pipefail

cd "$(dirname "$0")/.."
seconds="${FUZZ_SECONDS:-40}"
# A fixed seed: the same run explores the same mutations (up to how many fit in the time).
seed="${FUZZ_SEED:-1}"

if ! cargo +nightly --version >/dev/null 2>&1; then
    echo "SKIPPED fuzz: no nightly toolchain"
    exit 0
fi
if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked || exit 1
fi

# Release build with debug assertions, overflow checks and AddressSanitizer (cargo-fuzz's defaults);
# the sanitizer's allocator hooks are what make -malloc_limit_mb catch a single oversized allocation.
# Limits: one allocation over 512 MB is a crash (no reader asks for that much: the bag reader holds at
# most 256 MiB of chunks); the whole process may reach 2048 MB, because a bag input may fill the
# reader's 256 MiB and AddressSanitizer's quarantine keeps up to 256 MB of freed memory on top.
cargo +nightly fuzz build || exit 1

logs=fuzz/target/ci-logs
mkdir -p "$logs"
failed=()
for target in $(cargo +nightly fuzz list); do
    work="fuzz/target/ci-corpus/$target"
    rm -rf "$work"
    mkdir -p "$work"
    dirs=("$work" "fuzz/corpus/$target")
    if [ -d "fuzz/regressions/$target" ]; then
        dirs+=("fuzz/regressions/$target")
    fi
    echo "fuzz $target: ${seconds}s"
    if cargo +nightly fuzz run "$target" "${dirs[@]}" -- \
        -max_total_time="$seconds" -seed="$seed" -rss_limit_mb=2048 -malloc_limit_mb=512 -timeout=20 \
        -print_final_stats=1 >"$logs/$target.log" 2>&1; then
        grep -E '^stat::number_of_executed_units|^Done ' "$logs/$target.log" | sed "s/^/  /"
    else
        echo "  CRASH: last lines of $logs/$target.log:"
        tail -n 40 "$logs/$target.log" | sed "s/^/  /"
        failed+=("$target")
    fi
done

if [ "${#failed[@]}" -gt 0 ]; then
    echo "fuzz: crashes in ${failed[*]} (inputs in fuzz/artifacts/; see fuzz/README.md)"
    exit 1
fi
echo "fuzz: no crash"
