# Shared by the bench scripts (sourced, after `set -euo pipefail` and `cd` to the repository).

# A temporary folder $tmp, removed on exit (kept with KEEP=1), and $pids, the background
# processes killed on exit. With a binary path (BIN, built if it is the default and missing),
# the binary is copied into $tmp once and $bin names the copy: a rebuild during the run does
# not change it under the bench.
bench_setup() {
    tmp="$(mktemp -d)"
    pids=()
    trap bench_cleanup EXIT
    if [ "$#" -gt 0 ]; then
        local b="$1"
        if [ "$b" = ./target/release/terrastream ] && [ ! -x "$b" ]; then cargo build --release --quiet; fi
        for _ in $(seq 120); do [ -x "$b" ] && break; sleep 1; done
        cp "$b" "$tmp/terrastream"
        bin="$tmp/terrastream"
    fi
}

bench_cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    if [ -n "${KEEP:-}" ]; then echo "kept $tmp"; else rm -rf "$tmp"; fi
}

# A free TCP port of 127.0.0.1.
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# $tmp/NAME.lua: a wrk script cycling through the URLs of $tmp/NAME.txt (one per line), each
# thread starting at a random point of the list.
wrk_url_script() { # NAME [HEADER_NAME HEADER_VALUE]: requests of $tmp/NAME.txt, optionally with one header
    local headers="nil"
    [ $# -lt 3 ] || headers="{[\"$2\"] = \"$3\"}"
    cat >"$tmp/$1.lua" <<LUA
local headers = $headers
local urls = {}
for line in io.lines("$tmp/$1.txt") do urls[#urls + 1] = line end
local i = 0
function init(args)
    -- Threads start at different points of the list.
    i = math.random(#urls)
end
function request()
    i = i % #urls + 1
    return wrk.format("GET", urls[i], headers)
end
LUA
}

# A wrk latency (e.g. 812.00us, 3.21ms, 1.02s) in ms.
to_ms() {
    awk -v v="$1" 'BEGIN { n = v + 0; if (v ~ /us$/) n /= 1000; else if (v ~ /ms$/) n *= 1; else if (v ~ /s$/) n *= 1000; print n }'
}

# The figures of wrk's output FILE (run with --latency) on one line, LABEL padded to WIDTH:
# requests/s, p99, transfer/s, non-2xx answers, socket errors; appends "requests/s p99_ms" to
# SUMS.
wrk_report() { # FILE LABEL WIDTH SUMS
    local rps p99 bad errs xfer
    rps=$(awk '/^Requests\/sec:/ {print $2}' "$1")
    xfer=$(awk '/^Transfer\/sec:/ {print $2}' "$1")
    p99=$(awk '$1 == "99%" {print $2}' "$1")
    bad=$(awk '/Non-2xx or 3xx responses:/ {print $NF}' "$1")
    errs=$(awk '/Socket errors:/ {sub(/.*Socket errors: /, ""); print}' "$1")
    printf "  %-${3}s %12s req/s   p99 %9s   %9s/s   non-2xx: %s   socket errors: %s\n" "$2" "$rps" "$p99" "$xfer" "${bad:-0}" "${errs:-none}"
    echo "$rps $(to_ms "$p99")" >>"$4"
}

# moto's S3 server from the virtual environment $1 on a free port of 127.0.0.1 (in $pids),
# with bucket $2 created; exports the AWS_* variables that point terrastream at it and sets
# $moto_port.
start_moto() { # VENV BUCKET
    moto_port=$(free_port)
    "$1/bin/moto_server" -H 127.0.0.1 -p "$moto_port" >"$tmp/moto.log" 2>&1 &
    pids+=($!)
    for _ in $(seq 100); do curl -fs -o /dev/null "http://127.0.0.1:$moto_port/" && break; sleep 0.1; done
    curl -fs -o /dev/null -X PUT "http://127.0.0.1:$moto_port/$2" || { echo "moto on port $moto_port: cannot create the bucket $2" >&2; exit 1; }
    export AWS_ENDPOINT_URL="http://127.0.0.1:$moto_port" AWS_ACCESS_KEY_ID=bench AWS_SECRET_ACCESS_KEY=bench AWS_REGION=us-east-1
    unset AWS_ENDPOINT_URL_S3 AWS_PROFILE AWS_SESSION_TOKEN
}
