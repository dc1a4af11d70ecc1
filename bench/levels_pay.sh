#!/usr/bin/env bash
# Issue 13, "levels that pay": bytes streamed and primitives drawn per frame over the shipped
# flight (data/flight-orbit.json), before and after, at the same thresholds, on fuji and on a
# generated smooth terrain. "Before" is a bake by an earlier terrastream binary (every level
# stored) replayed with the earlier selection rule (the coarsest level under the threshold,
# `--flight-rule coarsest`); "after" a bake by this build (only levels that pay stored) replayed
# with the client's rule (the cheapest level under the threshold). Both are replayed by this
# build's `eval --flight` (everything resident, no fades: exact, no timing noise).
#
#   OLD=/path/to/old/terrastream bench/levels_pay.sh      # [THRESHOLDS="1 2 4"] [OUT=/tmp/levels-pay]
#
# OLD: a release binary built from a commit before levels had to pay (e.g. 5ce7e59):
#   git worktree add /tmp/old 5ce7e59 && (cd /tmp/old && cargo build --release)
set -euo pipefail
cd "$(dirname "$0")/.."
NEW=${NEW:-target/release/terrastream}
OLD=${OLD:?set OLD to a terrastream binary from before levels had to pay}
OUT=${OUT:-/tmp/levels-pay}
THRESHOLDS=${THRESHOLDS:-1 2 4}
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

row() { # FLIGHT_JSON TERRAIN BAKE THRESHOLD
    python3 -c '
import json, sys
f = json.load(open(sys.argv[1]))
fr = f["frames"]
n = len(fr)
mp = sum(x["primitives"] for x in fr) / n
pp = max(x["primitives"] for x in fr)
mb = sum(x["bytes"] for x in fr) / n
sb, nb, ov, dl = f["streamed_bytes"], f["streamed_blobs"], f["frames_over_threshold"], f["draws_per_level"]
print(f"{sys.argv[2]:<7} {sys.argv[4]:>5} {sys.argv[3]:<7} {nb:>7} {sb:>12} {mp:>12.0f} {pp:>12} {mb:>12.0f} {ov:>6} {dl}")
' "$@"
}

printf '%-7s %5s %-7s %7s %12s %12s %12s %12s %6s %s\n' terrain px bake blobs "streamed B" "mean prims" "peak prims" "mean B/frame" over "draws per level (all frames)"
for t in fuji smooth; do
    bake "$OLD" $t "$OUT/$t-before"
    bake "$NEW" $t "$OUT/$t-after"
    for th in $THRESHOLDS; do
        for which in before after; do
            rule=cheapest
            [ $which = before ] && rule=coarsest
            "$NEW" eval "$OUT/$t-$which" --out "$OUT/eval-$t-$which-$th" --flight data/flight-orbit.json \
                --flight-rule $rule --width 1280 --height 720 --threshold "$th" --distances 1 --azimuths 1 \
                --elevations 45 --no-frame-times --quiet >/dev/null 2>&1
            row "$OUT/eval-$t-$which-$th/flight.json" $t $which "$th"
        done
    done
done
echo "(1280×720, fov 60°, 30 fps over data/flight-orbit.json; 'over' = frames drawing a level over the threshold)"
