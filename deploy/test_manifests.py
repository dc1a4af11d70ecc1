#!/usr/bin/env python3
"""Checks of the rendered Kubernetes manifests and of deploy/Dockerfile that a schema cannot
make: how the objects fit together and with the binary (its exit codes, probe endpoints,
shutdown timeout, shard count, image user).

    test_manifests.py --dockerfile deploy/Dockerfile [--counts FILE] RENDERED.yaml...

Each RENDERED.yaml is the output of `kubectl kustomize DIR`. Prints one line per check
(`PASS name` or `FAIL name: why`); with --counts, writes "PASSED FAILED" to FILE for
deploy/check.sh's closing line; exits 1 when a check failed. Then it breaks copies of the
first rendered file on purpose and checks that each breakage is caught.
"""

from __future__ import annotations

import argparse
import copy
import os
import re
import shlex
import sys

import yaml

# The binary's exit codes that a retry cannot help: 2 (usage, clap) and 3 (input refused).
REFUSAL_EXIT_CODES = {2, 3}
CONTAINER = "terrastream"
SUBCOMMANDS = {"serve", "plan", "bake"}
SECRET_NAME = re.compile(r"TOKEN|SECRET|PASSWORD|ACCESS_KEY", re.IGNORECASE)
TOKEN_ENV = ("TERRASTREAM_ADMIN_TOKEN", "TERRASTREAM_READ_TOKEN")
S3_ENV = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY")


class CheckError(Exception):
    """A check's failure, with the reason."""


def need(cond: bool, why: str) -> None:
    if not cond:
        raise CheckError(why)


# --- reading the rendered objects -------------------------------------------------------------


def component(obj: dict) -> str | None:
    return ((obj.get("metadata") or {}).get("labels") or {}).get("app.kubernetes.io/component")


def name(obj: dict) -> str:
    return (obj.get("metadata") or {}).get("name", "?")


def of_kind(docs: list[dict], kind: str) -> list[dict]:
    return [d for d in docs if d.get("kind") == kind]


def one(docs: list[dict], kind: str, comp: str) -> dict:
    found = [d for d in of_kind(docs, kind) if component(d) == comp]
    need(len(found) == 1, f"{len(found)} {kind}s with app.kubernetes.io/component={comp}, want 1")
    return found[0]


def pod_spec(workload: dict) -> dict:
    return workload["spec"]["template"]["spec"]


def main_container(workload: dict) -> dict:
    cs = pod_spec(workload).get("containers") or []
    named = [c for c in cs if c.get("name") == CONTAINER]
    need(len(named) == 1, f"{workload['kind']} {name(workload)} has no container named {CONTAINER}")
    return named[0]


def workloads(docs: list[dict]) -> list[dict]:
    return [d for d in docs if d.get("kind") in ("Deployment", "StatefulSet", "DaemonSet", "Job")]


class Secret:
    """An env value that comes from a Secret."""

    def __init__(self, ref: dict):
        self.name, self.key, self.optional = ref.get("name"), ref.get("key"), ref.get("optional")

    def __repr__(self) -> str:
        return f"Secret({self.name}/{self.key})"


def env_of(container: dict, docs: list[dict]) -> dict:
    """The container's environment: envFrom ConfigMaps first, then env (which wins)."""
    env: dict = {}
    maps = {name(d): d.get("data") or {} for d in of_kind(docs, "ConfigMap")}
    for src in container.get("envFrom") or []:
        if "configMapRef" in src:
            env.update(maps.get(src["configMapRef"].get("name"), {}))
        elif "secretRef" in src:
            env[f"<all of Secret {src['secretRef'].get('name')}>"] = Secret(src["secretRef"])
    for e in container.get("env") or []:
        vf = e.get("valueFrom") or {}
        if "secretKeyRef" in vf:
            env[e["name"]] = Secret(vf["secretKeyRef"])
        elif "configMapKeyRef" in vf:
            ref = vf["configMapKeyRef"]
            env[e["name"]] = maps.get(ref.get("name"), {}).get(ref.get("key"))
        else:
            env[e["name"]] = e.get("value", "")
    return env


def expand(arg: str, env: dict) -> str:
    """Kubernetes' $(VAR) expansion of command and args."""
    return re.sub(r"\$\(([A-Za-z_][A-Za-z0-9_]*)\)", lambda m: str(env.get(m.group(1), m.group(0))), arg)


def flag(args: list[str], name_: str) -> str | None:
    """The value of `--name V` or `--name=V` in args."""
    for i, a in enumerate(args):
        if a == name_ and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(name_ + "="):
            return a.split("=", 1)[1]
    return None


def container_port(container: dict, port) -> int | None:
    """A probe's or a Service's port (number or name) as a container port number."""
    for p in container.get("ports") or []:
        if port == p.get("containerPort") or (isinstance(port, str) and port == p.get("name")):
            return p.get("containerPort")
    return None


def bind_port(env: dict) -> int:
    bind = env.get("TERRASTREAM_BIND")
    need(
        isinstance(bind, str) and re.fullmatch(r".*:\d+", bind or ""),
        f"TERRASTREAM_BIND={bind!r} has no port",
    )
    return int(bind.rsplit(":", 1)[1])


def as_int(v, what: str) -> int:
    try:
        return int(str(v).strip())
    except (TypeError, ValueError):
        raise CheckError(f"{what}={v!r} is not a number") from None


def pre_stop_sleep(container: dict) -> int:
    pre = ((container.get("lifecycle") or {}).get("preStop")) or {}
    if "sleep" in pre:
        return as_int(pre["sleep"].get("seconds"), "preStop.sleep.seconds")
    cmd = (pre.get("exec") or {}).get("command") or []
    if cmd and os.path.basename(cmd[0]) == "sleep" and len(cmd) == 2:
        return as_int(cmd[1], "preStop sleep")
    if cmd[:2] in (["sh", "-c"], ["/bin/sh", "-c"]) and len(cmd) == 3:
        m = re.fullmatch(r"\s*sleep\s+(\d+)\s*", cmd[2])
        if m:
            return int(m.group(1))
    raise CheckError(f"no preStop sleep (got {pre or 'none'})")


def failure_rules(job: dict) -> tuple[dict[str, set[int]], bool]:
    """podFailurePolicy: exit codes per action (In rules on the main container), and whether a
    DisruptionTarget condition is ignored."""
    rules = ((job["spec"].get("podFailurePolicy") or {}).get("rules")) or []
    codes: dict[str, set[int]] = {}
    ignores_disruption = False
    for r in rules:
        oe = r.get("onExitCodes")
        if oe:
            need(
                oe.get("operator") == "In",
                f"an {r.get('action')} rule uses operator {oe.get('operator')}, want In",
            )
            need(
                oe.get("containerName") in (None, CONTAINER),
                f"rule names container {oe.get('containerName')!r}",
            )
            codes.setdefault(r.get("action"), set()).update(oe.get("values") or [])
        for pc in r.get("onPodConditions") or []:
            if (
                pc.get("type") == "DisruptionTarget"
                and r.get("action") == "Ignore"
                and pc.get("status", "True") == "True"
            ):
                ignores_disruption = True
    return codes, ignores_disruption


# --- the checks ----------------------------------------------------------------------------------


def manifest_checks(docs: list[dict], docker: dict) -> list[tuple[str, callable]]:
    """(name, check) pairs; a check raises CheckError and may return a detail string."""

    def serve():
        return one(docs, "Deployment", "serve")

    def job(step: str):
        return one(docs, "Job", f"bake-{step}")

    def serve_env():
        return env_of(main_container(serve()), docs)

    def present():
        for kind, comp in (
            ("Deployment", "serve"),
            ("Service", "serve"),
            ("Job", "bake-plan"),
            ("Job", "bake-shards"),
            ("Job", "bake-finish"),
        ):
            one(docs, kind, comp)

    def indexed():
        mode = job("shards")["spec"].get("completionMode")
        need(mode == "Indexed", f"completionMode is {mode!r}")

    def per_index_retries():
        spec = job("shards")["spec"]
        b = spec.get("backoffLimitPerIndex")
        need(isinstance(b, int) and b >= 1, f"backoffLimitPerIndex={b!r}, want ≥ 1 so that exit 1 is retried")
        m, n = spec.get("maxFailedIndexes"), spec.get("completions")
        need(
            isinstance(m, int) and isinstance(n, int) and 0 <= m <= n,
            f"maxFailedIndexes={m!r} with completions={n!r}",
        )
        return f"backoffLimitPerIndex={b}, maxFailedIndexes={m}"

    def fail_index_codes():
        codes, _ = failure_rules(job("shards"))
        got = codes.get("FailIndex", set())
        need(got == REFUSAL_EXIT_CODES, f"FailIndex on {sorted(got)}, want {sorted(REFUSAL_EXIT_CODES)}")
        need(
            not codes.get("FailJob"),
            f"FailJob on {sorted(codes.get('FailJob', ()))}: one shard would stop all",
        )
        need(
            not codes.get("Ignore"),
            f"Ignore on exit codes {sorted(codes.get('Ignore', ()))}: retried forever",
        )

    def fail_job_codes(step):
        def check():
            codes, _ = failure_rules(job(step))
            got = codes.get("FailJob", set())
            need(got == REFUSAL_EXIT_CODES, f"FailJob on {sorted(got)}, want {sorted(REFUSAL_EXIT_CODES)}")
            need(not codes.get("Ignore"), f"Ignore on exit codes {sorted(codes.get('Ignore', ()))}")

        return check

    def ignores_disruption():
        for step in ("plan", "shards", "finish"):
            _, ign = failure_rules(job(step))
            need(ign, f"the {step} Job does not Ignore DisruptionTarget (evictions use up retries)")

    def restart_never():
        for step in ("plan", "shards", "finish"):
            rp = pod_spec(job(step)).get("restartPolicy")
            need(rp == "Never", f"the {step} Job has restartPolicy {rp!r} (podFailurePolicy needs Never)")

    def shard_count():
        plan = job("plan")
        args = main_container(plan).get("args") or []
        shards = flag(args, "--shards")
        n = job("shards")["spec"].get("completions")
        need(shards is not None, "the plan Job has no --shards")
        need(isinstance(n, int), f"completions={n!r} is not a number")
        need(as_int(shards, "--shards") == n, f"plan --shards={shards}, shards Job completions={n}")
        return f"{n} shards"

    def index_from_env():
        args = main_container(job("shards")).get("args") or []
        need(flag(args, "--shard") is None, "--shard given: every index would bake the same shard")
        need(flag(args, "--plan") is not None, "no --plan")
        need("--finish" not in args, "--finish in the shards Job")

    def one_tileset():
        out = {}
        for step, opt in (("plan", "--out"), ("shards", "--plan"), ("finish", "--plan")):
            c = main_container(job(step))
            v = flag(c.get("args") or [], opt)
            need(v is not None, f"the {step} Job has no {opt}")
            out[step] = expand(v, env_of(c, docs))
        need(len(set(out.values())) == 1, f"different tilesets: {out}")
        need(
            "--finish" in (main_container(job("finish")).get("args") or []), "the finish Job has no --finish"
        )
        return out["plan"]

    def vars_defined():
        for w in workloads(docs):
            c = main_container(w)
            env = env_of(c, docs)
            for a in (c.get("command") or []) + (c.get("args") or []):
                left = re.findall(r"\$\(([A-Za-z_][A-Za-z0-9_]*)\)", a)
                missing = [v for v in left if v not in env]
                need(
                    not missing,
                    f"{name(w)}: $({', '.join(missing)}) in {a!r} not in its environment (kept literally)",
                )

    def inputs_alike():
        seen = set()
        for step in ("plan", "shards", "finish"):
            w = job(step)
            vols = {v["name"]: v for v in pod_spec(w).get("volumes") or []}
            mounts = [(m, vols.get(m["name"], {})) for m in main_container(w).get("volumeMounts") or []]
            claims = [
                (m["mountPath"], v["persistentVolumeClaim"]["claimName"], bool(m.get("readOnly")))
                for m, v in mounts
                if "persistentVolumeClaim" in v
            ]
            need(claims, f"the {step} Job mounts no input volume")
            seen.add(tuple(sorted(claims)))
        need(len(seen) == 1, f"input mounts differ between the Jobs: {seen}")
        ((path, claim, ro),) = next(iter(seen))
        need(ro, "the inputs are mounted read-write")
        plan = main_container(job("plan"))
        env = env_of(plan, docs)
        args = [expand(a, env) for a in plan.get("args") or []]
        inputs = [a for a in args[1:] if a.startswith("/")]
        need(
            inputs and all(i == path or i.startswith(path.rstrip("/") + "/") for i in inputs),
            f"plan inputs {inputs} are not under the mount {path}",
        )
        return f"{claim} at {path}"

    def bake_gpu():
        for step in ("shards", "finish"):
            args = main_container(job(step)).get("args") or []
            g = flag(args, "--gpu")
            need(g in ("off", "auto", "on"), f"the {step} Job has --gpu {g!r} (bake has no env var for it)")

    def bind_matches_port():
        c = main_container(serve())
        port = bind_port(serve_env())
        need(container_port(c, port) == port, f"TERRASTREAM_BIND port {port} is not a containerPort")
        return f"port {port}"

    def probe(kind, paths):
        def check():
            c = main_container(serve())
            p = c.get(kind)
            if kind == "startupProbe" and p is None:
                return "none"
            need(p is not None, "missing")
            get = p.get("httpGet") or {}
            need(get.get("path") in paths, f"path {get.get('path')!r}, want {' or '.join(paths)}")
            port = container_port(c, get.get("port"))
            need(port == bind_port(serve_env()), f"port {get.get('port')!r} is not the listening port")
            return f"{get['path']} on {port}"

        return check

    def grace():
        w = serve()
        c = main_container(w)
        g = pod_spec(w).get("terminationGracePeriodSeconds", 30)
        t = as_int(serve_env().get("TERRASTREAM_SHUTDOWN_TIMEOUT", 10), "TERRASTREAM_SHUTDOWN_TIMEOUT")
        s = pre_stop_sleep(c)
        need(isinstance(g, int) and g > t + s, f"{g} ≤ {t} + {s}")
        return f"{g} > {t} + {s}"

    def log_json():
        v = serve_env().get("TERRASTREAM_LOG_FORMAT")
        need(v == "json", f"TERRASTREAM_LOG_FORMAT={v!r}")

    def tokens():
        env = serve_env()
        for var in TOKEN_ENV:
            v = env.get(var)
            need(isinstance(v, Secret), f"{var} is {'missing' if v is None else 'not a secretKeyRef'}")
            need(v.optional is not True, f"{var}'s secretKeyRef is optional")
        return ", ".join(f"{var} <- {env[var].name}/{env[var].key}" for var in TOKEN_ENV)

    def s3_creds():
        for w in workloads(docs):
            env = env_of(main_container(w), docs)
            for var in S3_ENV:
                need(isinstance(env.get(var), Secret), f"{name(w)}: {var} not from a Secret")

    def no_plain_secrets():
        for w in workloads(docs):
            for c in pod_spec(w).get("containers") or []:
                for e in c.get("env") or []:
                    need(
                        not (SECRET_NAME.search(e["name"]) and "value" in e),
                        f"{name(w)}: {e['name']} has a plain value",
                    )
        for cm in of_kind(docs, "ConfigMap"):
            bad = [k for k in (cm.get("data") or {}) if SECRET_NAME.search(k)]
            need(not bad, f"ConfigMap {name(cm)} holds {bad}")

    def refs_resolve():
        maps = {name(d) for d in of_kind(docs, "ConfigMap")}
        secrets = {
            name(d): set((d.get("data") or {}) | (d.get("stringData") or {})) for d in of_kind(docs, "Secret")
        }
        claims = {name(d) for d in of_kind(docs, "PersistentVolumeClaim")}
        for w in workloads(docs):
            c = main_container(w)
            for src in c.get("envFrom") or []:
                if "configMapRef" in src:
                    need(
                        src["configMapRef"]["name"] in maps,
                        f"{name(w)}: no ConfigMap {src['configMapRef']['name']}",
                    )
            for v in env_of(c, docs).values():
                if isinstance(v, Secret) and secrets:
                    need(v.key in secrets.get(v.name, set()), f"{name(w)}: no key {v.key} in Secret {v.name}")
            for vol in pod_spec(w).get("volumes") or []:
                pvc = vol.get("persistentVolumeClaim")
                if pvc and claims:
                    need(
                        pvc["claimName"] in claims, f"{name(w)}: no PersistentVolumeClaim {pvc['claimName']}"
                    )
        return "ConfigMaps; Secrets and claims " + ("too" if secrets else "left to the overlay")

    def service():
        svc = one(docs, "Service", "serve")
        w = serve()
        labels = w["spec"]["template"]["metadata"].get("labels") or {}
        sel = svc["spec"].get("selector") or {}
        need(sel and all(labels.get(k) == v for k, v in sel.items()), f"selector {sel} misses the serve pods")
        c = main_container(w)
        for p in svc["spec"].get("ports") or []:
            tp = p.get("targetPort", p.get("port"))
            need(
                container_port(c, tp) == bind_port(serve_env()),
                f"targetPort {tp!r} is not the container port",
            )
        return f"targetPort -> {bind_port(serve_env())}"

    def pdb():
        labels = serve()["spec"]["template"]["metadata"].get("labels") or {}
        for d in of_kind(docs, "PodDisruptionBudget"):
            sel = (d["spec"].get("selector") or {}).get("matchLabels") or {}
            need(sel and all(labels.get(k) == v for k, v in sel.items()), f"{name(d)} selects {sel}")
        return f"{len(of_kind(docs, 'PodDisruptionBudget'))} budget(s)"

    def non_root():
        uid = docker.get("uid")
        for w in workloads(docs):
            ps = pod_spec(w).get("securityContext") or {}
            for c in (pod_spec(w).get("containers") or []) + (pod_spec(w).get("initContainers") or []):
                cs = c.get("securityContext") or {}
                need(
                    cs.get("runAsNonRoot", ps.get("runAsNonRoot")) is True,
                    f"{name(w)}/{c['name']}: runAsNonRoot not set",
                )
                user = cs.get("runAsUser", ps.get("runAsUser"))
                need(user != 0, f"{name(w)}/{c['name']}: runAsUser 0")
                need(
                    user is None or uid is None or user == uid,
                    f"{name(w)}/{c['name']}: runAsUser {user}, the Dockerfile's USER is {uid}",
                )
        return f"uid {uid}"

    def hardened():
        for w in workloads(docs):
            for c in pod_spec(w).get("containers") or []:
                cs = c.get("securityContext") or {}
                who = f"{name(w)}/{c['name']}"
                need(cs.get("readOnlyRootFilesystem") is True, f"{who}: root filesystem writable")
                need(cs.get("allowPrivilegeEscalation") is False, f"{who}: privilege escalation allowed")
                need(
                    "ALL" in ((cs.get("capabilities") or {}).get("drop") or []),
                    f"{who}: capabilities not dropped",
                )
                need(not ((cs.get("capabilities") or {}).get("add")), f"{who}: capabilities added")
            need(
                pod_spec(w).get("automountServiceAccountToken") is False,
                f"{name(w)}: service account token mounted",
            )

    def writable_tmp():
        for w in workloads(docs):
            vols = {v["name"]: v for v in pod_spec(w).get("volumes") or []}
            c = main_container(w)
            tmp = [m for m in c.get("volumeMounts") or [] if m["mountPath"] == "/tmp"]
            need(tmp and "emptyDir" in vols.get(tmp[0]["name"], {}), f"{name(w)}: no emptyDir at /tmp")

    def resources():
        for w in workloads(docs):
            for c in pod_spec(w).get("containers") or []:
                r = c.get("resources") or {}
                for part in ("requests", "limits"):
                    for res in ("cpu", "memory"):
                        need(res in (r.get(part) or {}), f"{name(w)}/{c['name']}: no {part}.{res}")

    def one_image():
        images = {}
        for w in workloads(docs):
            for c in (pod_spec(w).get("containers") or []) + (pod_spec(w).get("initContainers") or []):
                images[f"{name(w)}/{c['name']}"] = c.get("image", "")
        distinct = set(images.values())
        need(len(distinct) == 1, f"images differ: {images}")
        image = distinct.pop()
        tag = image.rsplit("/", 1)[-1]
        need("@sha256:" in image or (":" in tag and not tag.endswith(":latest")), f"{image!r}: no pinned tag")
        return image

    def subcommands():
        for w in workloads(docs):
            c = main_container(w)
            need("command" not in c, f"{name(w)}: command overrides the image's ENTRYPOINT")
            args = c.get("args") or []
            need(args and args[0] in SUBCOMMANDS, f"{name(w)}: args start with {args[:1]}")
        need(main_container(serve())["args"][0] == "serve", "the Deployment does not run serve")

    def labelled():
        steps = {"config", "serve", "bake-plan", "bake-shards", "bake-finish"}
        for d in docs:
            c = component(d)
            need(c in steps, f"{d.get('kind')} {name(d)} has app.kubernetes.io/component={c!r}")

    return [
        ("workloads: serve Deployment + Service, plan/shards/finish Jobs", present),
        ("all objects: a component label that `kubectl apply -l` selects by", labelled),
        ("shards Job: completionMode Indexed", indexed),
        ("shards Job: backoffLimitPerIndex and maxFailedIndexes", per_index_retries),
        ("shards Job: podFailurePolicy FailIndex on exit codes exactly {2, 3}", fail_index_codes),
        ("plan Job: podFailurePolicy FailJob on exit codes exactly {2, 3}", fail_job_codes("plan")),
        ("finish Job: podFailurePolicy FailJob on exit codes exactly {2, 3}", fail_job_codes("finish")),
        ("bake Jobs: DisruptionTarget ignored", ignores_disruption),
        ("bake Jobs: restartPolicy Never", restart_never),
        ("shards Job: completions equal the plan's --shards", shard_count),
        ("shards Job: index from JOB_COMPLETION_INDEX (no --shard)", index_from_env),
        ("bake Jobs: plan --out, shards and finish --plan name one tileset", one_tileset),
        ("bake Jobs: inputs mounted alike, read-only, plan inputs under them", inputs_alike),
        ("bake Jobs: --gpu given (bake reads no env var for it)", bake_gpu),
        ("all: $(VAR) in args defined in the container's environment", vars_defined),
        ("serve: containerPort is TERRASTREAM_BIND's port", bind_matches_port),
        ("serve: readinessProbe GET /readyz on the container port", probe("readinessProbe", ("/readyz",))),
        ("serve: livenessProbe GET /healthz on the container port", probe("livenessProbe", ("/healthz",))),
        (
            "serve: startupProbe, if any, on /healthz or /readyz",
            probe("startupProbe", ("/healthz", "/readyz")),
        ),
        ("serve: terminationGracePeriodSeconds > shutdown timeout + preStop sleep", grace),
        ("serve: TERRASTREAM_LOG_FORMAT=json", log_json),
        ("serve: admin and read tokens from a Secret (secretKeyRef)", tokens),
        ("Service: selects the serve pods, targetPort is the container port", service),
        ("PodDisruptionBudget: selects the serve pods", pdb),
        ("all: S3 credentials from a Secret (secretKeyRef)", s3_creds),
        ("all: no secret as a plain env value or in a ConfigMap", no_plain_secrets),
        ("all: ConfigMaps, Secrets and claims referenced exist", refs_resolve),
        ("all: runAsNonRoot, runAsUser is the Dockerfile's USER", non_root),
        ("all: read-only root, no privilege escalation, drop ALL, no SA token", hardened),
        ("all: writable /tmp (emptyDir) beside the read-only root", writable_tmp),
        ("all: cpu and memory requests and limits", resources),
        ("all: one image, pinned tag", one_image),
        ("all: args start with a subcommand (ENTRYPOINT is the binary)", subcommands),
    ]


# --- the Dockerfile ---------------------------------------------------------------------------


# Where a binary built outside the image goes for BINARY_FROM=prebuilt (deploy/image-smoke.sh
# puts it there); not in the repository.
PREBUILT_DIR = "deploy/prebuilt/"


def parse_dockerfile(path: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, rest) with continuation lines joined and comments dropped."""
    out, cur = [], ""
    with open(path, encoding="utf-8") as f:
        text = f.read().splitlines(keepends=True)
    for line in text:
        s = line.rstrip("\n")
        if not cur and (not s.strip() or s.lstrip().startswith("#")):
            continue
        if cur and s.lstrip().startswith("#"):
            continue
        cur += s.rstrip("\\").rstrip() + " " if s.endswith("\\") else s
        if not s.endswith("\\"):
            ins, _, rest = cur.strip().partition(" ")
            out.append((ins.upper(), rest.strip()))
            cur = ""
    return out


def dockerfile_checks(path: str, repo: str) -> tuple[list[tuple[str, callable]], dict]:
    lines = parse_dockerfile(path)
    stages: list[list[tuple[str, str]]] = []
    for ins, rest in lines:
        if ins == "FROM":
            stages.append([])
        if stages:
            stages[-1].append((ins, rest))
    final = stages[-1] if stages else []
    info: dict = {}
    users = [rest for ins, rest in final if ins == "USER"]
    if users and re.fullmatch(r"\d+(:\d+)?", users[-1]):
        info["uid"] = int(users[-1].split(":")[0])
    env = {}
    for ins, rest in final:
        if ins == "ENV":
            for tok in shlex.split(rest):
                if "=" in tok:
                    k, v = tok.split("=", 1)
                    env[k] = v

    def healthcheck():
        hc = [rest for ins, rest in final if ins == "HEALTHCHECK"]
        need(hc, "no HEALTHCHECK in the final stage")
        need(not hc[-1].upper().startswith("NONE"), "HEALTHCHECK NONE")
        cmd = re.search(r"CMD\s+(.*)$", hc[-1])
        need(cmd, "HEALTHCHECK without CMD")
        return cmd.group(1)

    def user():
        need(users, "no USER in the final stage (runs as root)")
        need(users[-1].split(":")[0] not in ("0", "root"), f"USER {users[-1]}")
        need("uid" in info, f"USER {users[-1]} is not numeric (runAsNonRoot cannot verify a name)")
        return f"USER {users[-1]}"

    def locked():
        runs = [rest for st in stages for ins, rest in st if ins == "RUN" and "cargo build" in rest]
        need(
            runs and all("--locked" in r and "--release" in r for r in runs),
            "cargo build without --release --locked",
        )

    def deps_layer():
        first = stages[0] if stages else []
        copies = [rest for ins, rest in first if ins == "COPY"]
        need(
            copies and set(copies[0].split()) == {"Cargo.toml", "Cargo.lock", "./"},
            f"the first stage starts with COPY {copies[:1]}, want the manifest and lock file only",
        )
        need(len(stages) >= 3, f"{len(stages)} stages, want deps, build and runtime")

    def expose():
        ports = [int(p.split("/")[0]) for ins, rest in final if ins == "EXPOSE" for p in rest.split()]
        bind = env.get("TERRASTREAM_BIND", "")
        need(
            bind.endswith(":8080") or (ports and bind.endswith(f":{ports[0]}")), f"TERRASTREAM_BIND={bind!r}"
        )
        need(ports and bind.endswith(f":{ports[0]}"), f"EXPOSE {ports} vs TERRASTREAM_BIND={bind!r}")
        need(env.get("TERRASTREAM_GPU") == "off", f"TERRASTREAM_GPU={env.get('TERRASTREAM_GPU')!r}, want off")
        return bind

    def copy_sources():
        for st in stages:
            for ins, rest in st:
                if ins != "COPY" or "--from=" in rest:
                    continue
                parts = [p for p in rest.split() if not p.startswith("--")]
                for src in parts[:-1]:
                    # The prebuilt binary is put there by whoever builds with BINARY_FROM=prebuilt.
                    if src.startswith(PREBUILT_DIR):
                        continue
                    need(os.path.exists(os.path.join(repo, src)), f"COPY {src}: not in the repository")

    def binary_source():
        args = {}
        for ins, rest in lines:
            if ins == "ARG" and "=" in rest:
                k, v = rest.split("=", 1)
                args[k.strip()] = v.strip()
        names = {}
        for st in stages:
            m = re.fullmatch(r"(\S+)\s+AS\s+(\S+)", st[0][1], re.IGNORECASE)
            if m:
                names[m.group(2).lower()] = (m.group(1), st)
        need(args.get("BINARY_FROM") == "build", f"ARG BINARY_FROM={args.get('BINARY_FROM')!r}, want build (from source)")
        need("build" in names, "no stage `build`")
        need("binary" in names and names["binary"][0] == "${BINARY_FROM}", "no stage `FROM ${BINARY_FROM} AS binary`")
        pre = names.get("prebuilt")
        need(pre, "no stage `prebuilt`")
        copies = [rest.split() for ins, rest in pre[1] if ins == "COPY"]
        need(
            copies and copies[0][0].startswith(PREBUILT_DIR) and copies[0][-1] == "/terrastream",
            f"stage prebuilt: COPY {copies[:1]}, want {PREBUILT_DIR}terrastream /terrastream",
        )
        finals = [rest for ins, rest in final if ins == "COPY" and "--from=" in rest]
        need(any("--from=binary " in r for r in finals), f"the final stage copies {finals}, want --from=binary")
        ign = os.path.join(repo, PREBUILT_DIR, ".gitignore")
        need(os.path.exists(ign), f"no {PREBUILT_DIR}.gitignore (a prebuilt binary would show in git status)")
        return "BINARY_FROM=build (default) | prebuilt"

    def dockerignore():
        ign = path + ".dockerignore"
        need(os.path.exists(ign), f"no {os.path.basename(ign)}")
        with open(ign, encoding="utf-8") as f:
            pats = {ln.strip().rstrip("/") for ln in f if ln.strip() and not ln.startswith("#")}
        for p in ("target", ".git"):
            need(p in pats, f"{p}/ not excluded")

    return [
        ("Dockerfile: HEALTHCHECK in the final stage", healthcheck),
        ("Dockerfile: numeric non-root USER in the final stage", user),
        ("Dockerfile: cargo build --release --locked", locked),
        ("Dockerfile: dependency layer from Cargo.toml + Cargo.lock, then build, then runtime", deps_layer),
        ("Dockerfile: EXPOSE is TERRASTREAM_BIND's port, TERRASTREAM_GPU=off", expose),
        ("Dockerfile: COPY sources exist", copy_sources),
        ("Dockerfile: the binary from `build`, or deploy/prebuilt/ with BINARY_FROM=prebuilt", binary_source),
        ("Dockerfile.dockerignore: excludes target/ and .git/", dockerignore),
    ], info


# --- running -----------------------------------------------------------------------------------


def run(checks, label: str, counts: list[int]) -> None:
    for title, fn in checks:
        try:
            detail = fn()
        except CheckError as e:
            counts[1] += 1
            print(f"FAIL {label}{title}: {e}")
        except (KeyError, TypeError, IndexError, AttributeError, ValueError) as e:
            counts[1] += 1
            print(f"FAIL {label}{title}: malformed ({type(e).__name__}: {e})")
        else:
            counts[0] += 1
            print(f"PASS {label}{title}" + (f" ({detail})" if detail else ""))


def fails(checks, title: str) -> bool:
    """Whether the check fails with its own reason (not on malformed objects)."""
    try:
        dict(checks)[title]()
    except CheckError:
        return True
    return False


def breakages():
    """(what, the check that must catch it, how to break the objects)."""

    def find(docs, kind, comp):
        return next(d for d in docs if d.get("kind") == kind and component(d) == comp)

    def ctr(docs, kind, comp):
        return main_container(find(docs, kind, comp))

    def set_codes(docs, values):
        for r in find(docs, "Job", "bake-shards")["spec"]["podFailurePolicy"]["rules"]:
            if r.get("onExitCodes"):
                r["onExitCodes"]["values"] = values

    def grace(docs):
        pod_spec(find(docs, "Deployment", "serve"))["terminationGracePeriodSeconds"] = 20

    def readiness(docs):
        ctr(docs, "Deployment", "serve")["readinessProbe"]["httpGet"]["path"] = "/healthz"

    def target_port(docs):
        find(docs, "Service", "serve")["spec"]["ports"][0]["targetPort"] = 9090

    def completions(docs):
        find(docs, "Job", "bake-shards")["spec"]["completions"] += 1

    def root(docs):
        w = find(docs, "Job", "bake-plan")
        pod_spec(w).get("securityContext", {}).pop("runAsNonRoot", None)
        main_container(w).get("securityContext", {}).pop("runAsNonRoot", None)

    def plain_token(docs):
        for e in ctr(docs, "Deployment", "serve")["env"]:
            if e["name"] == "TERRASTREAM_READ_TOKEN":
                e.pop("valueFrom")
                e["value"] = "change-me-read"

    def non_indexed(docs):
        find(docs, "Job", "bake-shards")["spec"]["completionMode"] = "NonIndexed"

    def latest(docs):
        c = ctr(docs, "Job", "bake-finish")
        c["image"] = c["image"].rsplit(":", 1)[0] + ":latest"

    def undefined_var(docs):
        c = ctr(docs, "Job", "bake-plan")
        c["args"] = [a.replace("$(BAKE_TILESET)", "$(BAKE_TILESETS)") for a in c["args"]]

    def unlabelled(docs):
        cm = next(d for d in docs if d.get("kind") == "ConfigMap")
        cm["metadata"]["labels"].pop("app.kubernetes.io/component")

    return [
        (
            "ConfigMap without a component label",
            "all objects: a component label that `kubectl apply -l` selects by",
            unlabelled,
        ),
        (
            "FailIndex also on exit 1",
            "shards Job: podFailurePolicy FailIndex on exit codes exactly {2, 3}",
            lambda d: set_codes(d, [1, 2, 3]),
        ),
        (
            "FailIndex on exit 3 only",
            "shards Job: podFailurePolicy FailIndex on exit codes exactly {2, 3}",
            lambda d: set_codes(d, [3]),
        ),
        (
            "grace period 20 s",
            "serve: terminationGracePeriodSeconds > shutdown timeout + preStop sleep",
            grace,
        ),
        ("readinessProbe on /healthz", "serve: readinessProbe GET /readyz on the container port", readiness),
        (
            "Service targetPort 9090",
            "Service: selects the serve pods, targetPort is the container port",
            target_port,
        ),
        (
            "completions one more than --shards",
            "shards Job: completions equal the plan's --shards",
            completions,
        ),
        ("plan Job without runAsNonRoot", "all: runAsNonRoot, runAsUser is the Dockerfile's USER", root),
        (
            "read token as a plain value",
            "serve: admin and read tokens from a Secret (secretKeyRef)",
            plain_token,
        ),
        ("completionMode NonIndexed", "shards Job: completionMode Indexed", non_indexed),
        ("finish Job on :latest", "all: one image, pinned tag", latest),
        ("a misspelt $(VAR)", "all: $(VAR) in args defined in the container's environment", undefined_var),
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rendered", nargs="+", help="`kubectl kustomize DIR` outputs")
    ap.add_argument("--dockerfile", required=True)
    ap.add_argument("--counts", help="write 'PASSED FAILED' here")
    a = ap.parse_args()
    repo = os.path.dirname(os.path.dirname(os.path.abspath(a.dockerfile)))
    counts = [0, 0]

    dchecks, docker = dockerfile_checks(a.dockerfile, repo)
    run(dchecks, "", counts)
    rendered = {}
    for path in a.rendered:
        with open(path, encoding="utf-8") as f:
            docs = [d for d in yaml.safe_load_all(f) if d]
        rendered[path] = docs
        run(manifest_checks(docs, docker), f"{os.path.basename(path)}: ", counts)

    # The checks must catch these; each is made on a copy of the first rendered kustomization.
    first = a.rendered[0]
    for what, title, breaks in breakages():
        docs = copy.deepcopy(rendered[first])
        breaks(docs)
        if fails(manifest_checks(rendered[first], docker), title):
            counts[1] += 1
            print(f"FAIL breakage test: '{title}' fails before anything is broken")
        elif fails(manifest_checks(docs, docker), title):
            counts[0] += 1
            print(f"PASS breakage caught: {what} -> '{title}'")
        else:
            counts[1] += 1
            print(f"FAIL breakage not caught: {what} passed '{title}'")

    if a.counts:
        with open(a.counts, "w", encoding="utf-8") as f:
            f.write(f"{counts[0]} {counts[1]}\n")
    return 1 if counts[1] else 0


if __name__ == "__main__":
    sys.exit(main())
