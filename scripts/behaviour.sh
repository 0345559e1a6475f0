#!/usr/bin/env bash
# Records what a dc_loc binary computes on the built-in drives, so that two builds can be compared byte
# for byte (a restructuring must leave every result as it was).
#
#   scripts/behaviour.sh record BIN DIR [--quick]   run BIN's commands, write their results under DIR
#   scripts/behaviour.sh compare DIR_A DIR_B        diff two recordings; exit 0 when identical
#
# Recorded: `dc_loc demo` (its tables with the run time and paths masked, the per-pair results and the
# plot) and `dc_loc revisits` (the table and every judged closure, `--closures-out`) on the dev and the
# held-out worlds with the ARS408 set and the forward radar, Gaussian and Student-t noise, 1 and 3 %
# drift, and on held-out fleets of three robots. `--quick` keeps the demo, the held-out fleets and one
# dev scenario (about 4 minutes on two cores instead of about 25).
set -euo pipefail

usage() { sed -n '4,5p' "$0" >&2; exit 2; }

record() {
    local bin=$1 dir=$2 quick=${3:-}
    bin=$(realpath "$bin")
    mkdir -p "$dir"
    dir=$(realpath "$dir")
    cd "$dir"
    echo "demo" >&2
    "$bin" demo --out demo-out 2>/dev/null \
        | sed -E -e "s#$dir/##g" -e 's/^demo finished in .*/demo finished/' > demo.txt
    cp demo-out/pairs.jsonl demo-pairs.jsonl
    cp demo-out/eval.svg demo-eval.svg
    rm -rf demo-out
    local runs
    if [ "$quick" = "--quick" ]; then
        runs=(
            "fleet-test|--set test --radars nuscenes,carla --drift 1 --fleet 3"
            "dev-gaussian-1|--set dev --radars nuscenes,carla --noise gaussian --drift 1"
        )
    else
        runs=(
            "fleet-test|--set test --radars nuscenes,carla --drift 1 --fleet 3"
            "dev|--set dev --radars nuscenes,carla --noise gaussian,student-t --drift 1,3"
            "test|--set test --radars nuscenes,carla --noise gaussian,student-t --drift 1,3"
        )
    fi
    local run name args
    for run in "${runs[@]}"; do
        name=${run%%|*}
        args=${run#*|}
        echo "revisits $args" >&2
        # shellcheck disable=SC2086
        "$bin" revisits $args --closures-out "revisits-$name.jsonl" 2>/dev/null > "revisits-$name.txt"
    done
}

compare() {
    local a=$1 b=$2
    if diff -r "$a" "$b" > /dev/null; then
        for f in "$a"/*; do
            printf '%s identical (%s lines)\n' "$(basename "$f")" "$(wc -l < "$f")"
        done
        echo "identical"
    else
        diff -r "$a" "$b" | head -40
        echo "DIFFERENT"
        return 1
    fi
}

case "${1:-}" in
    record) [ $# -ge 3 ] || usage; record "$2" "$3" "${4:-}" ;;
    compare) [ $# -eq 3 ] || usage; compare "$2" "$3" ;;
    *) usage ;;
esac
