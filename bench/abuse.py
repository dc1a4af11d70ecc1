#!/usr/bin/env python3
"""Connection abuse against a running `terrastream serve` (see bench/abuse.sh).

Opens IDLE idle connections spread over many loopback source addresses (127.0.1.x), SLOW
slowloris connections (127.0.2.x) that trickle a request head at 1 byte/s, and GREEDY idle
connections from one address (127.0.0.9); meanwhile a normal client (127.0.0.1) requests
/healthz and a blob every 0.5 s on fresh connections. Prints the normal client's latencies and
failures, and when the server closed each group of abusive connections.

Usage: abuse.py HOST:PORT BLOB_PATH DURATION_S [IDLE SLOW GREEDY]
"""

import selectors
import socket
import statistics
import sys
import threading
import time
import urllib.request


def main():
    host, port = sys.argv[1].rsplit(":", 1)
    port = int(port)
    blob = sys.argv[2]
    duration = float(sys.argv[3])
    n_idle, n_slow, n_greedy = (int(x) for x in (sys.argv[4:7] or ["2000", "500", "4100"]))
    sel = selectors.DefaultSelector()
    t0 = time.monotonic()
    # One record per socket (not keyed by descriptor: closed descriptors are reused).
    socks = []

    def open_group(group, n, source):
        for i in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind((source(i), 0))
            s.setblocking(False)
            s.connect_ex((host, port))
            st = {"group": group, "sock": s, "opened": time.monotonic(), "closed": None, "got": b""}
            socks.append(st)
            sel.register(s, selectors.EVENT_READ, st)
            if i % 200 == 199:
                pump(0.05)

    def pump(timeout):
        for key, _ in sel.select(timeout):
            st = key.data
            try:
                data = st["sock"].recv(4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if data:
                st["got"] += data[:200]
                continue
            st["closed"] = time.monotonic()
            sel.unregister(st["sock"])
            st["sock"].close()

    open_group("idle", n_idle, lambda i: f"127.0.1.{1 + i % 200}")
    open_group("slowloris", n_slow, lambda i: f"127.0.2.{1 + i % 50}")
    open_group("greedy", n_greedy, lambda _: "127.0.0.9")
    opened = time.monotonic() - t0
    print(f"opened {n_idle} idle (200 addresses), {n_slow} slowloris (50 addresses), {n_greedy} idle from one address in {opened:.1f} s")

    # The normal client, on its own thread with fresh connections.
    results = {"healthz": [], "blob": []}
    failures = []
    stop = threading.Event()

    def normal():
        base = f"http://{host}:{port}"
        while not stop.is_set():
            for name, path in (("healthz", "/healthz"), ("blob", blob)):
                start = time.monotonic()
                try:
                    with urllib.request.urlopen(base + path, timeout=10) as r:
                        r.read()
                        ok = r.status == 200
                except Exception as e:  # noqa: BLE001 - any failure is a finding
                    ok = False
                    failures.append(f"{name} at {start - t0:.1f} s: {e}")
                if ok:
                    results[name].append((time.monotonic() - start) * 1e3)
            stop.wait(0.5)

    th = threading.Thread(target=normal, daemon=True)
    th.start()

    head = b"GET /healthz HTTP/1.1\r\nHost: x\r\n" + b"X-Slow: " + b"a" * 4000
    sent = 0
    next_byte = time.monotonic()
    while time.monotonic() - t0 < duration:
        pump(0.2)
        if time.monotonic() >= next_byte:
            next_byte += 1.0
            for st in socks:
                if st["group"] == "slowloris" and st["closed"] is None and sent < len(head):
                    try:
                        st["sock"].send(head[sent : sent + 1])
                    except OSError:
                        pass
            sent += 1
    stop.set()
    th.join(timeout=15)

    def pct(v, p):
        v = sorted(v)
        return v[min(len(v) - 1, int(round(p / 100 * (len(v) - 1))))] if v else float("nan")

    for name, v in results.items():
        print(
            f"normal client {name}: {len(v)} answered 200, p50 {pct(v, 50):.1f} ms, p99 {pct(v, 99):.1f} ms, max {max(v) if v else float('nan'):.1f} ms"
        )
    print(f"normal client failures: {len(failures)}")
    for f in failures[:10]:
        print("  " + f)
    for group in ("idle", "slowloris", "greedy"):
        g = [st for st in socks if st["group"] == group]
        closed = [st["closed"] - st["opened"] for st in g if st["closed"] is not None]
        refused = sum(1 for st in g if st["got"].startswith(b"HTTP/1.1 503"))
        fast = sum(1 for c in closed if c < 2.0)
        line = f"{group}: {len(g)} opened, {len(closed)} closed by the server within {duration:.0f} s"
        if closed:
            line += f" (median after {statistics.median(closed):.1f} s, max {max(closed):.1f} s; {fast} within 2 s, {refused} with a 503)"
        print(line)
    for st in socks:
        if st["closed"] is None:
            st["sock"].close()


if __name__ == "__main__":
    main()
