#!/usr/bin/env bash
# Plays a Kubernetes Indexed Job on one machine: runs COMMAND once per completion index with
# JOB_COMPLETION_INDEX set, at most --parallelism at a time, retrying a failed index up to
# --backoff-limit-per-index times (backoffLimitPerIndex) with a doubling delay, and failing an
# index at once when its exit status is one of --fail-index-codes (the podFailurePolicy's
# FailIndex rule: the input was refused, a retry cannot succeed). --shuffle starts the indexes
# in a random order. Exits 0 when every index succeeded; prints one line per index outcome and a
# closing "indexes: N succeeded, N failed".
#
#   deploy/run-indexed-job.sh --completions 16 --parallelism 2 -- terrastream bake --plan OUT
set -euo pipefail

completions="" parallelism=1 backoff=3 shuffle=0 fail_codes="2 3" delay0=0.5
while [ $# -gt 0 ]; do
  case "$1" in
    --completions) completions="$2"; shift 2 ;;
    --parallelism) parallelism="$2"; shift 2 ;;
    --backoff-limit-per-index) backoff="$2"; shift 2 ;;
    --fail-index-codes) fail_codes="${2//,/ }"; shift 2 ;;
    --retry-delay) delay0="$2"; shift 2 ;;
    --shuffle) shuffle=1; shift ;;
    --) shift; break ;;
    *) echo "run-indexed-job: unknown option $1" >&2; exit 2 ;;
  esac
done
if ! [[ "$completions" =~ ^[0-9]+$ ]] || [ "$completions" -lt 1 ] || [ $# -eq 0 ]; then
  echo "usage: $0 --completions N [--parallelism P] [--backoff-limit-per-index R] [--shuffle] -- COMMAND..." >&2
  exit 2
fi
if ! [[ "$parallelism" =~ ^[0-9]+$ && "$backoff" =~ ^[0-9]+$ ]] || [ "$parallelism" -lt 1 ]; then
  echo "run-indexed-job: --parallelism must be ≥ 1 and --backoff-limit-per-index ≥ 0" >&2
  exit 2
fi

order=$(seq 0 $((completions - 1)))
if [ "$shuffle" -eq 1 ]; then order=$(printf '%s\n' $order | shuf); fi
# Indexes wait in this queue (a retried one goes to its end, as the Job controller requeues it).
queue=($order)
declare -A tries=() pid_index=()
succeeded=0 failed=0
logdir=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$logdir"' EXIT

start() {
  local i=$1; shift
  tries[$i]=$(( ${tries[$i]:-0} + 1 ))
  if [ "${tries[$i]}" -gt 1 ]; then
    # Backoff before a retry: delay0 · 2^(tries-2).
    sleep "$(awk -v d="$delay0" -v n="${tries[$i]}" 'BEGIN { print d * 2 ^ (n - 2) }')"
  fi
  JOB_COMPLETION_INDEX=$i "$@" > "$logdir/$i.${tries[$i]}.log" 2>&1 &
  pid_index[$!]=$i
}

while [ ${#queue[@]} -gt 0 ] || [ ${#pid_index[@]} -gt 0 ]; do
  while [ ${#queue[@]} -gt 0 ] && [ ${#pid_index[@]} -lt "$parallelism" ]; do
    start "${queue[0]}" "$@"
    queue=("${queue[@]:1}")
  done
  rc=0
  wait -n -p done_pid "${!pid_index[@]}" || rc=$?
  i=${pid_index[$done_pid]}
  unset "pid_index[$done_pid]"
  if [ "$rc" -eq 0 ]; then
    succeeded=$((succeeded + 1))
    echo "index $i: succeeded (attempt ${tries[$i]})"
  elif [[ " $fail_codes " == *" $rc "* ]]; then
    failed=$((failed + 1))
    echo "index $i: failed at once (exit $rc, input refused): $(tail -n 1 "$logdir/$i.${tries[$i]}.log")"
  elif [ "${tries[$i]}" -le "$backoff" ]; then
    echo "index $i: attempt ${tries[$i]} failed (exit $rc), retrying: $(tail -n 1 "$logdir/$i.${tries[$i]}.log")"
    queue+=("$i")
  else
    failed=$((failed + 1))
    echo "index $i: failed after ${tries[$i]} attempts (exit $rc): $(tail -n 1 "$logdir/$i.${tries[$i]}.log")"
  fi
done
echo "indexes: $succeeded succeeded, $failed failed"
[ "$failed" -eq 0 ]
