#!/usr/bin/env bash
# Runs the fuzzing campaign: every target, one at a time (one fuzzer process, one job), each
# for at least MIN_EXECS executions and MAX_TIME seconds, whichever comes later (the issue's
# bar: 10 million executions or 30 minutes). A crash, timeout or OOM is kept under
# fuzz/artifacts/<target>/ and the target restarts on its grown corpus, at most MAX_RESTARTS
# times, until both budgets are spent. Prints per target the executions, seconds, corpus size
# and findings, and appends the table to fuzz/RESULTS.md.
#
#   fuzz/run-campaign.sh                       # the full campaign (about 14 × 30 min or more)
#   MAX_TIME=200 MIN_EXECS=0 LABEL="short" fuzz/run-campaign.sh codec_blob raster_geotiff
#
# Needs nightly and cargo-fuzz (`cargo install cargo-fuzz`). Builds once, without a sanitizer
# (the project is safe Rust; the findings are panics, overflows, timeouts and OOMs) and with
# debug assertions, so integer overflow panics as it does in `cargo test` (SKIP_BUILD=1: use
# the binaries already built).
set -euo pipefail

cd "$(dirname "$0")"
MAX_TIME=${MAX_TIME:-1800}
MIN_EXECS=${MIN_EXECS:-10000000}
MAX_RESTARTS=${MAX_RESTARTS:-5}
RSS_LIMIT_MB=${RSS_LIMIT_MB:-512}
LABEL=${LABEL:-"full campaign (MAX_TIME=${MAX_TIME}s, MIN_EXECS=${MIN_EXECS})"}
# Where the table goes: two campaigns side by side (one per core) each write their own file.
RESULTS=${RESULTS:-RESULTS.md}
TRIPLE=$(rustc +nightly -vV | sed -n 's/^host: //p')
BIN=target/$TRIPLE/release

max_len() {
    case $1 in
        raster_hgt|flight_json|config_toml|http_router) echo 4096 ;;
        codec_roundtrip) echo 2048 ;;
        store_archive) echo 32768 ;;
        *) echo 16384 ;;
    esac
}

if [ $# -gt 0 ]; then targets=("$@"); else mapfile -t targets < <(cargo +nightly fuzz list); fi

[ -n "${SKIP_BUILD:-}" ] || cargo +nightly fuzz build -O -s none

{
    echo
    echo "### $(date -u +%Y-%m-%d\ %H:%MZ) — $LABEL"
    echo
    echo "Host: $(nproc) cores; rss limit ${RSS_LIMIT_MB} MB, timeout 1 s, one process per campaign, sanitizer none, debug assertions on."
    echo
    echo "| target | executions | seconds | exec/s | corpus files | corpus bytes | crash files | timeout files | oom files | new artifacts |"
    echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
} >>"$RESULTS"

for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    seeds=()
    [ -d "seeds/$t" ] && seeds=("seeds/$t")
    before=$(find "artifacts/$t" -type f | wc -l)
    execs=0
    start=$(date +%s)
    restarts=0
    while :; do
        elapsed=$(( $(date +%s) - start ))
        left_time=$(( MAX_TIME - elapsed ))
        left_execs=$(( MIN_EXECS - execs ))
        if [ "$left_time" -le 0 ] && [ "$left_execs" -le 0 ]; then break; fi
        limit=()
        if [ "$left_time" -gt 0 ]; then limit+=("-max_total_time=$left_time"); fi
        # Past the time budget, keep going only until the execution budget is met.
        if [ "$left_time" -le 0 ]; then limit+=("-runs=$left_execs"); fi
        log=$(mktemp)
        set +e
        "$BIN/$t" "corpus/$t" "${seeds[@]}" -rss_limit_mb="$RSS_LIMIT_MB" -timeout=1 \
            -max_len="$(max_len "$t")" -print_final_stats=1 -artifact_prefix="artifacts/$t/" \
            "${limit[@]}" >"$log" 2>&1
        rc=$?
        set -e
        n=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
        execs=$(( execs + ${n:-0} ))
        if [ "$rc" -ne 0 ]; then
            echo "== $t: fuzzer exited $rc; last lines:" >&2
            grep -E 'ERROR|panicked|SUMMARY|Test unit written' "$log" | tail -8 >&2 || true
            restarts=$(( restarts + 1 ))
        fi
        rm -f "$log"
        if [ "$restarts" -gt "$MAX_RESTARTS" ]; then break; fi
    done
    secs=$(( $(date +%s) - start ))
    files=$(find "corpus/$t" -type f | wc -l)
    bytes=$(find "corpus/$t" -type f -printf '%s\n' | awk '{s += $1} END {print s + 0}')
    count() { find "artifacts/$t" -type f -name "$1-*" | wc -l; }
    crashes=$(count crash); timeouts=$(count timeout); ooms=$(count oom)
    new=$(( $(find "artifacts/$t" -type f | wc -l) - before ))
    row="| $t | $execs | $secs | $(( execs / (secs > 0 ? secs : 1) )) | $files | $bytes | $crashes | $timeouts | $ooms | $new |"
    echo "$row"
    echo "$row" >>"$RESULTS"
done

