#!/usr/bin/env bash
# Sharded bake against a one-machine bake of the same raster, and what writing a tileset into
# object storage costs as files against as one archive. A generated float32 GeoTIFF of SIZE²
# samples in 256² tiles (BigTIFF past 4 GiB; 4.3 GB at 32769²) is written once and kept in
# target/bench-cache/. Then, each step run under GNU time (wall seconds and peak RSS of that
# process):
#   - one machine: `bake --gpu off -q` with all cores;
#   - for each shard count N: `plan --shards N`, the N shards `bake --plan OUT` through
#     deploy/run-indexed-job.sh --parallelism PARALLEL (a Kubernetes Indexed Job played on this
#     machine: JOB_COMPLETION_INDEX set), each shard with --threads cores/PARALLEL so the
#     workers share the machine's cores as the one-machine bake has them, then
#     `bake --plan OUT --finish`. Total wall time = plan + shards + finish, against the one
#     machine's; the sharded tileset must be byte for byte the one-machine one (diff -r);
#   - object storage (moto's S3 server on 127.0.0.1, a free port): the same bake with
#     --out s3://… ("directory to S3": one object per file; counted, and compared with the
#     directory's files by MD5), and `pack` of the directory into one .tsa archive, written
#     locally and with --out s3://….tsa (one object). Skipped with a message when
#     `terrastream pack --help` fails (pack not there yet) or moto is not installed.
# Files written = every file of the finished tileset (tiles, index, manifest) and its bytes.
#
# Then, on paper, from the measured figures, a 1 m DEM of 500 km × 500 km (S_big = 2.5·10¹¹
# samples) on K = 16, 64, 256 workers of the same size, all at once: every process (plan, each
# shard, finish) opens the whole dataset (its opening scan reads every sample), so a shard's wall
# is t_open + its samples / r_b; the sums of the shard walls at the smallest and largest shard
# count give t_open and r_b (one count: t_open = 0, r_b = the raw rate). At full scale t_open,
# plan and finish are scaled linearly in samples (an upper bound for the finish). Printed: time
# per shard and in all, worker-hours, peak RSS per worker (the largest shard's; flat in the size
# per dataset_rss.sh), objects (directory: files per sample × S_big; archive: one, packed from the
# finished tileset), storage (bytes per sample × S_big), with the arithmetic.
# Bytes per sample come from the synthetic terrain (CELL m cells, default 10 as the other
# benches); a real DEM's differ with its roughness against --max-error. moto is a Python server
# on the same cores: its times are not S3's, its object counts are.
#
# Targets (this bench's): sharded tileset identical to the one machine's; sharded total wall
# ≤ 1.15 × the one machine's (the same cores: splitting costs the plan, the finish and every
# shard's opening scan of the whole dataset); every step's peak RSS ≤ 1024 MiB (dataset_rss.sh's target).
#
# Needs GNU time (/usr/bin/time: apt-get install time), curl, and for the S3 phase moto's server
# with boto3 in $TERRASTREAM_CI_VENV (default ~/.cache/terrastream-ci-venv, as .ci/run makes).
# Env: BIN (default target/release/terrastream, built if missing), TILE_SIZE (default 256; small
# sizes need a smaller one to have N leaf tiles), CELL (default 10), KEEP=1 keeps the temp dir,
# SKIP_S3=1 leaves out the object-storage phase.
# Usage: bench/sharded_bake.sh [SIZE=32769] [SHARDS="4 16"] [PARALLEL=2]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-32769}"
shard_counts="${2:-4 16}"
parallel="${3:-2}"
tile="${TILE_SIZE:-256}"
cell="${CELL:-10}"
venv="${TERRASTREAM_CI_VENV:-$HOME/.cache/terrastream-ci-venv}"
py="$venv/bin/python"
big=250000000000 # 500 km × 500 km at 1 m
workers_big="16 64 256"

[ -x /usr/bin/time ] || { echo "needs GNU time: apt-get install time" >&2; exit 1; }

source bench/lib.sh
BIN="${BIN:-./target/release/terrastream}"
bench_setup "$BIN"
threads_one=$(nproc)
threads_worker=$(( $(nproc) / parallel )); ((threads_worker >= 1)) || threads_worker=1

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: $0 $size \"$shard_counts\" $parallel (TILE_SIZE=$tile CELL=$cell BIN=$BIN; $(git describe --always --dirty 2>/dev/null || echo '?'))"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo); one machine: --threads $threads_one; shards: $parallel at a time, --threads $threads_worker each"

# The raster, generated once.
cache=target/bench-cache
mkdir -p "$cache"
tif="$cache/synth-${size}-cell${cell}-seed1-t256.tif"
if [ ! -s "$tif" ]; then
    echo "generating $tif …"
    "$bin" synth --width "$size" --cell-size "$cell" --seed 1 --tiled 256 --out "$tif.tmp" >/dev/null
    mv "$tif.tmp" "$tif"
fi
tif="$(realpath "$tif")"
samples=$((size * size))
echo "raster: $tif, ${size}x${size} = $samples samples, $(stat -c %s "$tif") bytes"
bake_opts=(--tile-size "$tile" --gpu off -q)

# step NAME CMD… : runs CMD under GNU time; "NAME wall_s rss_kib" goes to $tmp/steps.
step() {
    local name=$1; shift
    if ! /usr/bin/time -f '%e %M' -o "$tmp/$name.time" "$@" >"$tmp/$name.log" 2>&1; then
        echo "$name failed:" >&2; tail -n 20 "$tmp/$name.log" >&2; exit 1
    fi
    echo "$name $(cat "$tmp/$name.time")" >>"$tmp/steps"
}
wall() { awk -v n="$1" '$1 == n {print $2}' "$tmp/steps"; }
rss_mib() { awk -v n="$1" '$1 == n {printf "%.0f", $3 / 1024}' "$tmp/steps"; }
files_of() { find "$1" -type f | wc -l; }
bytes_of() { find "$1" -type f -printf '%s\n' | awk '{s += $1} END {print s + 0}'; }
now() { date +%s.%N; }
spread() { # COLUMN FILE → "min median max" of that column
    cut -d' ' -f"$1" "$2" | sort -g | awk '{v[NR] = $1} END {print v[1], v[int((NR + 1) / 2)], v[NR]}'
}
rows=()
row() { rows+=("$(printf '%-34s %9s %9s %11s %14s   %s' "$@")"); }

# One machine.
step one "$bin" bake "$tif" --out "$tmp/one" "${bake_opts[@]}" --threads "$threads_one"
one_wall=$(wall one); one_files=$(files_of "$tmp/one"); one_bytes=$(bytes_of "$tmp/one")
echo "one machine: $one_wall s, peak RSS $(rss_mib one) MiB, $one_files files, $one_bytes bytes ($(sed -n 1p "$tmp/one.log"))"
row "one machine" "$one_wall" "$(rss_mib one)" "$one_files" "$one_bytes" "(reference)"

# One shard under GNU time, as run-indexed-job.sh starts it (JOB_COMPLETION_INDEX set); a
# retried index overwrites its figures with the last attempt's.
cat >"$tmp/shard.sh" <<EOF
#!/usr/bin/env bash
exec /usr/bin/time -f '%e %M' -o "\$SHARD_DIR/shard-\$JOB_COMPLETION_INDEX.time" \\
    "$bin" bake --plan "\$SHARD_OUT" --gpu off -q --threads $threads_worker >"\$SHARD_DIR/shard-\$JOB_COMPLETION_INDEX.log" 2>&1
EOF
chmod +x "$tmp/shard.sh"
identical=1
shard_rss_max=0
: >"$tmp/fit" # per shard count: "N sum_of_shard_walls plan_wall finish_wall"
for n in $shard_counts; do
    out="$tmp/sharded-$n"
    mkdir -p "$tmp/shards-$n"
    t0=$(now)
    step "plan-$n" "$bin" plan "$tif" --out "$out" --shards "$n" --tile-size "$tile" -q
    t1=$(now)
    if ! SHARD_DIR="$tmp/shards-$n" SHARD_OUT="$out" deploy/run-indexed-job.sh --completions "$n" \
        --parallelism "$parallel" -- "$tmp/shard.sh" >"$tmp/job-$n.log" 2>&1; then
        echo "shards of $n failed:" >&2; cat "$tmp/job-$n.log" >&2; exit 1
    fi
    t2=$(now)
    step "finish-$n" "$bin" bake --plan "$out" --finish --gpu off -q
    t3=$(now)
    retries=$(grep -c 'retrying' "$tmp/job-$n.log" || true)
    # Per shard: "index wall_s rss_kib".
    for ((i = 0; i < n; i++)); do echo "$i $(cat "$tmp/shards-$n/shard-$i.time")"; done >"$tmp/shards-$n.txt"
    sum_wall=$(awk '{s += $2} END {printf "%.2f", s}' "$tmp/shards-$n.txt")
    read -r sw_min sw_med sw_max < <(spread 2 "$tmp/shards-$n.txt")
    read -r sr_min sr_med sr_max < <(spread 3 "$tmp/shards-$n.txt" | awk '{printf "%.0f %.0f %.0f\n", $1 / 1024, $2 / 1024, $3 / 1024}')
    total=$(awk -v a="$t0" -v b="$t3" 'BEGIN {printf "%.2f", b - a}')
    shards_wall=$(awk -v a="$t1" -v b="$t2" 'BEGIN {printf "%.2f", b - a}')
    rate=$(awk -v s="$samples" -v w="$sum_wall" 'BEGIN {printf "%.0f", s / w}')
    ((sr_max > shard_rss_max)) && shard_rss_max=$sr_max
    echo "$n $sum_wall $(wall "plan-$n") $(wall "finish-$n")" >>"$tmp/fit"
    if diff -r -q "$tmp/one" "$out" >"$tmp/diff-$n.txt" 2>&1; then
        same="identical to one machine (diff -r, $(files_of "$out") files)"; same_n=identical
    else
        same="DIFFERS from one machine: $(head -3 "$tmp/diff-$n.txt" | tr '\n' ';')"; same_n=DIFFERS
        identical=0
    fi
    echo "$n shards: total $total s (plan $(wall "plan-$n") s, $n shards $shards_wall s, finish $(wall "finish-$n") s); $(tail -1 "$tmp/job-$n.log"), $retries retried attempts"
    echo "  per shard: wall min/median/max $sw_min/$sw_med/$sw_max s (sum $sum_wall s), peak RSS min/median/max $sr_min/$sr_med/$sr_max MiB"
    echo "  per worker: $samples samples / $sum_wall s = $rate samples/s (--threads $threads_worker)"
    echo "  $same"
    ratio=$(awk -v a="$total" -v b="$one_wall" 'BEGIN {printf "%.2f", a / b}')
    row "$n shards, total ($parallel at a time)" "$total" "$sr_max" "$(files_of "$out")" "$(bytes_of "$out")" "$ratio × one machine (target ≤ 1.15); $same_n"
    row "  plan" "$(wall "plan-$n")" "$(rss_mib "plan-$n")" "" "" ""
    row "  $n shards (wall of the job)" "$shards_wall" "$sr_max" "" "" "per shard: median $sw_med s, max $sw_max s; RSS max of the shards"
    row "  finish" "$(wall "finish-$n")" "$(rss_mib "finish-$n")" "" "" ""
    rm -rf "$out"
done

# Object storage: moto's S3 server on a free port of 127.0.0.1.
s3_note=""
pack_note=""
if ! "$bin" pack --help >/dev/null 2>&1; then
    pack_note="skipped: \`terrastream pack --help\` fails (this binary has no pack yet)"
fi
if [ -n "${SKIP_S3:-}" ]; then
    s3_note="skipped: SKIP_S3 set"
elif [ ! -x "$venv/bin/moto_server" ] || ! "$py" -c 'import boto3' 2>/dev/null; then
    s3_note="skipped: no moto_server/boto3 in $venv (python3 -m venv $venv && $venv/bin/pip install 'moto[server]' boto3)"
else
    start_moto "$venv" bench
    echo "S3: moto on 127.0.0.1:$moto_port, bucket bench"

    step s3-dir "$bin" bake "$tif" --out s3://bench/dir/tileset "${bake_opts[@]}" --threads "$threads_one"
    read -r s3_objects s3_bytes < <("$py" bench/s3_upload.py count s3://bench/dir/tileset)
    s3_same=$("$py" bench/s3_upload.py compare s3://bench/dir/tileset "$tmp/one") && s3_same_n="identical (MD5)" \
        || { identical=0; s3_same="DIFFERS: $s3_same"; s3_same_n=DIFFERS; }
    echo "directory to S3: $(wall s3-dir) s, $s3_objects objects, $s3_bytes bytes; $s3_same"
    row "directory to S3 (bake --out s3://)" "$(wall s3-dir)" "$(rss_mib s3-dir)" "$s3_objects" "$s3_bytes" \
        "$(awk -v a="$(wall s3-dir)" -v b="$one_wall" 'BEGIN {printf "%.2f", a / b}') × one machine; $(awk -v o="$s3_objects" -v w="$(wall s3-dir)" 'BEGIN {printf "%.0f", o / w}') objects/s; $s3_same_n"
    "$py" bench/s3_upload.py rm s3://bench/dir/tileset >/dev/null # moto holds objects in memory

    if [ -z "$pack_note" ]; then
        step pack-local "$bin" pack "$tmp/one" --out "$tmp/tileset.tsa" -q
        tsa_bytes=$(stat -c %s "$tmp/tileset.tsa")
        echo "pack -> local file: $(wall pack-local) s, $tsa_bytes bytes ($(sed -n 1p "$tmp/pack-local.log"))"
        row "archive: pack -> local .tsa" "$(wall pack-local)" "$(rss_mib pack-local)" 1 "$tsa_bytes" \
            "$(awk -v a="$tsa_bytes" -v b="$one_bytes" 'BEGIN {printf "%.4f", a / b}') × the directory's bytes"
        rm -f "$tmp/tileset.tsa"
        step pack-s3 "$bin" pack "$tmp/one" --out s3://bench/archive/tileset.tsa -q
        read -r a_objects a_bytes < <("$py" bench/s3_upload.py count s3://bench/archive)
        echo "pack -> S3: $(wall pack-s3) s, $a_objects object(s) under s3://bench/archive/, $a_bytes bytes"
        row "archive: pack --out s3://.../x.tsa" "$(wall pack-s3)" "$(rss_mib pack-s3)" "$a_objects" "$a_bytes" \
            "$(awk -v a="$(wall pack-s3)" -v b="$one_wall" -v c="$(wall s3-dir)" 'BEGIN {printf "one machine + this = %.2f s, %.2f × the bake into S3", a + b, (a + b) / c}')"
    fi
fi

echo
printf '%-34s %9s %9s %11s %14s   %s\n' step "wall s" "RSS MiB" "files/objs" "bytes" "notes"
printf '%s\n' "${rows[@]}"
[ -n "$s3_note" ] && printf '%-34s %s\n' "object storage" "$s3_note"
[ -n "$pack_note" ] && printf '%-34s %s\n' "archive (pack)" "$pack_note"
all_rss=$(awk '{printf "%.0f\n", $3 / 1024}' "$tmp/steps" | sort -n | tail -1)
((shard_rss_max > all_rss)) && all_rss=$shard_rss_max
echo "peak RSS of any step: $all_rss MiB (target ≤ 1024 MiB)"
echo "sharded tilesets identical to the one machine's: $( ((identical)) && echo yes || echo NO) (target: yes)"

# On paper. Every process opens the dataset whole (plan, each shard, finish: the opening scan
# reads every sample for the checksum and statistics), so a shard's wall is about
# t_open + (its samples)/r_b: the sums of the shard walls at two shard counts N1 < N2 give
# t_open = (sum2 - sum1)/(N2 - N1) and r_b = S/(sum1 - N1·t_open). At full scale t_open grows
# with the dataset (× S_big/S) and is paid by every worker.
echo
echo "On paper: a 1 m DEM of 500 km × 500 km, S_big = 2.5e11 samples, on K workers of $threads_worker core(s) each (all at once)"
sort -n "$tmp/fit" | awk -v S="$big" -v s="$samples" -v rss="$shard_rss_max" -v B="$one_bytes" -v F="$one_files" -v ks="$workers_big" '
function dur(t) { return t >= 3600 ? sprintf("%.1f h", t / 3600) : t >= 60 ? sprintf("%.1f min", t / 60) : sprintf("%.1f s", t) }
{ n[NR] = $1; sw[NR] = $2; pl[NR] = $3; fi[NR] = $4 }
END {
    m = NR
    printf "measured: sum of shard walls: "
    for (i = 1; i <= m; i++) printf "%s%d shards %.2f s (%d samples/s per worker)", (i > 1 ? ", " : ""), n[i], sw[i], s / sw[i]
    printf "\n"
    if (m >= 2 && n[m] > n[1]) {
        to = (sw[m] - sw[1]) / (n[m] - n[1])
        printf "  t_open = (%.2f - %.2f) / (%d - %d) = %.3f s per process at %d samples\n", sw[m], sw[1], n[m], n[1], to, s
        if (to < 0) { printf "  (negative: noise; taken as 0, r_b = the lowest rate)\n"; to = 0 }
    } else {
        to = 0
        printf "  one shard count: no fit; t_open = 0 and r_b = the lowest rate (opening cost inside r_b)\n"
    }
    rb = s / (sw[1] - n[1] * to)
    if (to == 0) for (i = 1; i <= m; i++) if (s / sw[i] < rb) rb = s / sw[i]
    if (to > 0) printf "  r_b = %d / (%.2f - %d × %.3f) = %d samples/s per worker\n", s, sw[1], n[1], to, rb
    else printf "  r_b = %d samples/s per worker\n", rb
    b = B / s; o = F / s; g = S / s
    printf "  bytes/sample b = %d / %d = %.4f; files/sample o = %d / %d = %.4e; peak RSS per worker %d MiB (assumed flat in the size, as dataset_rss.sh measures)\n", B, s, b, F, s, o, rss
    printf "  plan %.2f s, finish %.2f s (the %d-shard run)\n", pl[m], fi[m], n[m]
    printf "scale g = S_big / S = %.4g / %d = %.4g\n", S, s, g
    printf "storage            = S_big · b = %.4g × %.4f = %.3f TB (any K)\n", S, b, S * b / 1e12
    printf "objects, directory = S_big · o = %.4g × %.4e = %.4g (any K; one PUT each)\n", S, o, S * o
    printf "objects, archive   = 1 (pack of the finished tileset: bake onto a shared filesystem, then one multipart upload; baked into a bucket first, the %.4g PUTs above come first and pack GETs each once)\n", S * o
    ob = to * g; pb = pl[m] * g; fb = fi[m] * g
    printf "open per worker    = t_open · g = %.3f × %.4g = %.0f s (%s)\n", to, g, ob, dur(ob)
    printf "plan, finish       = %.2f · g = %.0f s, %.2f · g = %.0f s (linear in S: an upper bound for the finish, whose own baking is the K/3 tiles above the shards)\n", pl[m], pb, fi[m], fb
    printf "shard              = open + S_big / (K · r_b)\n"
    printf "%6s %14s %12s %12s %12s %10s %12s\n", "K", "samples/shard", "shard", "total", "worker-h", "RSS/worker", "storage"
    nk = split(ks, k, " ")
    for (i = 1; i <= nk; i++) {
        K = k[i]; t = ob + S / (K * rb)
        printf "%6d %14.4g %12s %12s %12.1f %6d MiB %9.3f TB   shard = %.0f + %.4g/(%d × %d) = %.0f s; total = %.0f + %.0f + %.0f s\n", \
            K, S / K, dur(t), dur(pb + t + fb), K * t / 3600, rss, S * b / 1e12, ob, S, K, rb, t, pb, t, fb
    }
}'
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
((identical))
