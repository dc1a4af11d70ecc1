#!/usr/bin/env bash
# Issue 13, "levels that pay": bytes streamed and primitives drawn per frame over the shipped
# flight (data/flight-orbit.json), before and after, at the same threshold, on fuji and on a
# generated smooth terrain. "Before" is a bake by an earlier terrastream binary (every level
# stored, coarsest level under the threshold drawn), "after" one by this build (only levels that
# pay stored, the cheapest level under the threshold drawn). Both are replayed by this build's
# `eval --flight` (everything resident, no fades: exact, no timing noise), "before" with
# `--flight-rule coarsest` (the selection rule of the earlier binary).
#
#   OLD=/path/to/old/terrastream bench/levels_pay.sh            # [THRESHOLD=1] [OUT=/tmp/levels-pay]
#
# OLD: a release binary built from a commit before levels had to pay (e.g. 5ce7e59):
#   git worktree add /tmp/old 5ce7e59 && (cd /tmp/old && cargo build --release)
set -euo pipefail
cd "$(dirname "$0")/.."
NEW=${NEW:-target/release/terrastream}
OLD=${OLD:?set OLD to a terrastream binary from before levels had to pay}
OUT=${OUT:-/tmp/levels-pay}
THRESHOLD=${THRESHOLD:-1}
SHARED=${SHARED:-../shared}
[ -x "$NEW" ] || cargo build --release
rm -rf "$OUT"
mkdir -p "$OUT"
"$NEW" synth --out "$OUT/smooth.tif" --width 2625 --cell-size 10 >/dev/null

bake() { # BIN NAME DIR
    case $2 in
        fuji) "$1" bake "$SHARED/data/fuji.png" --encoding terrain-rgb --cell-size 30 --gpu off --quiet --out "$3" ;;
        smooth) "$1" bake "$OUT/smooth.tif" --tile-size 64 --gpu off --quiet --out "$3" ;;
    esac >/dev/null 2>&1
}

printf '%-7s %-7s %10s %12s %12s %12s %12s %8s\n' terrain bake "blobs" "streamed B" "mean prims" "peak prims" "mean B/frame" "over"
for t in fuji smooth; do
    for which in before after; do
        bin=$NEW rule=cheapest
        [ $which = before ] && bin=$OLD rule=coarsest
        bake "$bin" $t "$OUT/$t-$which"
        "$NEW" eval "$OUT/$t-$which" --out "$OUT/eval-$t-$which" --flight data/flight-orbit.json \
            --flight-rule $rule --width 1280 --height 720 --threshold "$THRESHOLD" --distances 1 --azimuths 1 --elevations 45 --no-frame-times \
            --quiet >/dev/null 2>&1
        python3 - "$OUT/eval-$t-$which/flight.json" "$t" "$which" <<'EOF'
import json, sys
f = json.load(open(sys.argv[1]))
fr = f["frames"]
n = len(fr)
mp = sum(x["primitives"] for x in fr) / n
pp = max(x["primitives"] for x in fr)
mb = sum(x["bytes"] for x in fr) / n
print(f"{sys.argv[2]:<7} {sys.argv[3]:<7} {f['streamed_blobs']:>10} {f['streamed_bytes']:>12} {mp:>12.0f} {pp:>12} {mb:>12.0f} {f['frames_over_threshold']:>8}")
EOF
    done
done
echo "(threshold $THRESHOLD px, 1280×720, fov 60°, 30 fps; 'over' = frames drawing a level over the threshold)"
