#!/usr/bin/env bash
# `terrastream export --format 3dtiles` of a whole tileset: a generated SIZE×SIZE raster (10 m
# cells) baked once with the default options on the CPU path (`--gpu off`), kept under
# target/bench/export_3dtiles/SIZE/ (re-baked when the release binary changes), then exported
# RUNS times into a fresh folder on the same disk. Prints each run's wall time, GLBs/s, MB/s
# (GLB bytes written; 1 MB = 10^6 B) and peak RSS (/usr/bin/time -v), the median run, and the
# GLB total next to the blob total, per level. Anchors from the same run: `cp -r` of the blob
# tree, RUNS times (the same number of files copied: the file system's own cost for a tree of
# that many files) and the bake itself (timed when it was made, this run or the one that cached it).
#
# Usage: bench/export_3dtiles.sh [SIZE=4097] [RUNS=5]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-4097}"
runs="${2:-5}"
cargo build --release --quiet
bin=./target/release/terrastream
cache="target/bench/export_3dtiles/$size"
stamp="$(sha256sum "$bin" | cut -c1-16) $size"

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: $0 $size $runs ($(git describe --always --dirty 2>/dev/null || echo '?'))"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)"
if [ "$(cat "$cache/stamp" 2>/dev/null)" != "$stamp" ] || [ ! -f "$cache/store/tileset.json" ]; then
    rm -rf "$cache" && mkdir -p "$cache"
    "$bin" synth --width "$size" --cell-size 10 --out "$cache/synth.tif" >/dev/null
    t0=$(date +%s.%N)
    "$bin" bake --quiet --gpu off "$cache/synth.tif" --out "$cache/store" >/dev/null
    t1=$(date +%s.%N)
    awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.2f\n", b - a}' >"$cache/bake_s"
    rm -f "$cache/synth.tif"
    echo "$stamp" >"$cache/stamp"
    echo "baked: $bin bake --quiet --gpu off synth.tif (${size}x${size}, 10 m cells) in $(cat "$cache/bake_s") s (this run)"
else
    echo "bake: cached in $cache (same binary), baked in $(cat "$cache/bake_s") s when it was made"
fi
store="$cache/store"
blobs=$(find "$store/tiles" -name '*.tsb' | wc -l)
blob_bytes=$(find "$store/tiles" -name '*.tsb' -printf '%s\n' | awk '{s += $1} END {print s}')
echo "tileset: ${size}x${size} samples, $blobs blobs, $blob_bytes bytes"

out="$cache/3dtiles"
timed() { # LOG CMD… → runs CMD under /usr/bin/time -v (if any), prints "wall_s peak_rss_kib cpu_s"
    local log="$1"; shift
    if [ -x /usr/bin/time ]; then
        /usr/bin/time -v -o "$log.time" "$@" >"$log" 2>&1
        awk -F': ' '/Elapsed \(wall clock\)/ {n = split($2, p, ":"); w = 0; for (i = 1; i <= n; i++) w = w * 60 + p[i]}
                    /Maximum resident set size/ {r = $2} /^\tUser time|^\tSystem time/ {c += $2}
                    END {printf "%.2f %d %.2f\n", w, r, c}' "$log.time"
    else
        local t0 t1
        t0=$(date +%s.%N); "$@" >"$log" 2>&1; t1=$(date +%s.%N)
        awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.2f 0 0\n", b - a}'
    fi
}
echo "export: $bin export $store --format 3dtiles --out $out --quiet   ($runs runs, the output folder removed before each)"
rm -f "$cache/runs.txt"
for ((i = 1; i <= runs; i++)); do
    rm -rf "$out"
    sync
    read -r wall rss cpu < <(timed "$cache/export.log" "$bin" export "$store" --format 3dtiles --out "$out" --quiet)
    glbs=$(find "$out/tiles" -name '*.glb' | wc -l)
    glb_bytes=$(find "$out/tiles" -name '*.glb' -printf '%s\n' | awk '{s += $1} END {print s}')
    ((glbs == blobs)) || { echo "export wrote $glbs GLBs for $blobs blobs" >&2; exit 1; }
    echo "$wall $rss $cpu" >>"$cache/runs.txt"
    awk -v w="$wall" -v r="$rss" -v c="$cpu" -v n="$glbs" -v b="$glb_bytes" -v bb="$blob_bytes" -v i="$i" 'BEGIN {
        printf "  run %d: %6.2f s (CPU %5.2f s)   %7.0f GLBs/s   %6.1f MB/s written (%5.1f MB/s of blobs read)   peak RSS %5.1f MiB\n",
            i, w, c, n / w, b / w / 1e6, bb / w / 1e6, r / 1024 }'
done
echo "  export says: $(cat "$cache/export.log")"
read -r med_wall med_rss med_cpu < <(sort -g "$cache/runs.txt" | awk '{w[NR] = $1; r[NR] = $2; c[NR] = $3} END {m = int((NR + 1) / 2); print w[m], r[m], c[m]}')

# Anchor: copying the blob tree (same file count) on the same disk, as many times (median).
rm -f "$cache/cp.txt"
for ((i = 1; i <= runs; i++)); do
    rm -rf "$cache/copy"
    sync
    timed "$cache/cp.log" cp -r "$store/tiles" "$cache/copy" >>"$cache/cp.txt"
done
rm -rf "$cache/copy"
read -r cp_wall cp_rss cp_cpu < <(sort -g "$cache/cp.txt" | awk '{w[NR] = $1; r[NR] = $2; c[NR] = $3} END {m = int((NR + 1) / 2); print w[m], r[m], c[m]}')

echo
echo "median of $runs runs each (by wall time):"
awk -v w="$med_wall" -v r="$med_rss" -v c="$med_cpu" -v cc="$cp_cpu" -v n="$blobs" -v b="$glb_bytes" -v bb="$blob_bytes" -v cw="$cp_wall" \
    -v cr="$cp_rss" -v bake="$(cat "$cache/bake_s")" 'BEGIN {
    printf "  %-32s %6.2f s (CPU %5.2f s)   %6.0f files/s   %6.1f MB/s written   peak RSS %6.1f MiB\n",
        "export --format 3dtiles", w, c, n / w, b / w / 1e6, r / 1024
    printf "  %-32s %6.2f s (CPU %5.2f s)   %6.0f files/s   %6.1f MB/s written   peak RSS %6.1f MiB\n",
        "anchor: cp -r of the blob tree", cw, cc, n / cw, bb / cw / 1e6, cr / 1024
    printf "  %-32s %6.2f s\n", "anchor: the bake (--gpu off)", bake
    printf "  export / cp -r = %.1fx   export / bake = %.2f\n", w / cw, w / bake
}'

echo
echo "GLB vs blob bytes, per level (B/file = mean file size; positions: GLBs with UNSIGNED_SHORT / FLOAT positions):"
# Position component type of every GLB (the first chunk is the glTF JSON).
python3 - "$out/tiles" >"$cache/postypes.txt" <<'EOF'
import json, os, struct, sys
counts = {}
for root, _, files in os.walk(sys.argv[1]):
    for name in files:
        with open(os.path.join(root, name), "rb") as f:
            head = f.read(20)
            jlen = struct.unpack_from("<I", head, 12)[0]
            doc = json.loads(head[20:] + f.read(jlen))
        acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
        c = counts.setdefault(name[:-4], [0, 0])
        c[acc["componentType"] == 5126] += 1
for level, (u16, f32) in counts.items():
    print(level, u16, f32)
EOF
printf '  %5s %6s %6s | %12s %9s | %12s %9s | %8s | %s\n' level kind files "blob B" "B/file" "GLB B" "B/file" "GLB/blob" "positions u16/float"
levels=$(find "$store/tiles" -name '*.tsb' -printf '%f\n' | sed 's/\.tsb$//' | sort -un)
for l in $levels; do
    kind=$(jq -r --argjson l "$l" '.levels[] | select(.level == $l) | .kind' "$store/tileset.json")
    n=$(find "$store/tiles" -name "$l.tsb" | wc -l)
    bb=$(find "$store/tiles" -name "$l.tsb" -printf '%s\n' | awk '{s += $1} END {print s}')
    gb=$(find "$out/tiles" -name "$l.glb" -printf '%s\n' | awk '{s += $1} END {print s}')
    printf '  %5s %6s %6d | %12d %9d | %12d %9d | %8.2f | %s\n' "$l" "$kind" "$n" "$bb" $((bb / n)) "$gb" $((gb / n)) \
        "$(awk -v a="$gb" -v b="$bb" 'BEGIN {print a / b}')" "$(awk -v l="$l" '$1 == l {print $2 "/" $3}' "$cache/postypes.txt")"
done
printf '  %5s %6s %6d | %12d %9d | %12d %9d | %8.2f\n' all "" "$blobs" "$blob_bytes" $((blob_bytes / blobs)) \
    "$glb_bytes" $((glb_bytes / blobs)) "$(awk -v a="$glb_bytes" -v b="$blob_bytes" 'BEGIN {print a / b}')"
jsons=$(find "$out" -name '*.json' | wc -l)
json_bytes=$(find "$out" -name '*.json' -printf '%s\n' | awk '{s += $1} END {print s}')
echo "  + $jsons tileset JSON files, $json_bytes bytes"
rm -rf "$out"
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
