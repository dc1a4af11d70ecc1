//! Prometheus text-format metrics: requests by route and status, latency histograms by route,
//! bytes sent, blob cache hits and misses, corrupt blobs, shed requests, on-demand bake queue
//! depth, bakes done and failed. Counters are atomics or short critical sections, cheap enough
//! for every request.

use std::collections::HashMap;
use std::fmt::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::time::Duration;

/// Upper bounds of the latency histogram buckets, in seconds.
const BUCKETS: [f64; 14] =
    [0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0];

#[derive(Default)]
struct Histogram {
    counts: [u64; BUCKETS.len()],
    count: u64,
    sum: f64,
}

/// Counters of one route: requests by status and the latency histogram.
#[derive(Default)]
struct RouteStats {
    statuses: Vec<(u16, u64)>,
    latency: Histogram,
}

#[derive(Default)]
pub struct Metrics {
    /// By route pattern (a bounded set: the router's routes and "unmatched"). One lock and no
    /// allocation per request once a route has been seen.
    routes: Mutex<HashMap<String, RouteStats>>,
    pub bytes_sent: AtomicU64,
    pub cache_hits: AtomicU64,
    pub cache_misses: AtomicU64,
    pub corrupt_blobs: AtomicU64,
    pub shed: AtomicU64,
    pub bake_queue_depth: AtomicI64,
    pub bakes_running: AtomicI64,
    pub bakes_done: AtomicU64,
    pub bakes_failed: AtomicU64,
    pub connections_open: AtomicI64,
    /// Connections refused because their client address was at its connection cap.
    pub connections_refused: AtomicU64,
    /// Connections closed after `--idle-timeout` with no request in flight.
    pub connections_idle_closed: AtomicU64,
    /// Connections closed because a request head took longer than `--header-timeout`.
    pub connections_header_timeouts: AtomicU64,
    /// Connections a busy serving thread handed to a less busy one, at accept or idle
    /// (`--cpu-affinity`).
    pub connections_moved: AtomicU64,
    /// Requests the wire-level fast path answered itself (in-memory blobs and GLBs), counted in
    /// the per-route figures too.
    pub wire_answers: AtomicU64,
}

impl Metrics {
    pub fn record(&self, route: &str, status: u16, elapsed: Duration) {
        let s = elapsed.as_secs_f64();
        let Ok(mut m) = self.routes.lock() else { return };
        let r = if let Some(r) = m.get_mut(route) { r } else { m.entry(route.to_owned()).or_default() };
        if let Some(c) = r.statuses.iter_mut().find(|(st, _)| *st == status) {
            c.1 += 1;
        } else {
            r.statuses.push((status, 1));
        }
        let h = &mut r.latency;
        // Stored per bucket; rendered cumulatively as Prometheus expects.
        if let Some(i) = BUCKETS.iter().position(|&b| s <= b) {
            h.counts[i] += 1;
        }
        h.count += 1;
        h.sum += s;
    }

    /// The count of requests to `route` answered with `status` (for tests and the soak).
    #[must_use]
    pub fn requests(&self, route: &str, status: u16) -> u64 {
        let Ok(m) = self.routes.lock() else { return 0 };
        m.get(route).and_then(|r| r.statuses.iter().find(|(st, _)| *st == status)).map_or(0, |c| c.1)
    }

    #[must_use]
    pub fn render(&self) -> String {
        let mut out = String::new();
        let esc = |s: &str| s.replace('\\', "\\\\").replace('"', "\\\"");
        out.push_str("# HELP terrastream_http_requests_total HTTP requests by route and status.\n");
        out.push_str("# TYPE terrastream_http_requests_total counter\n");
        let routes = self.routes.lock().ok();
        let mut sorted: Vec<_> = routes.iter().flat_map(|m| m.iter()).collect();
        sorted.sort_by(|a, b| a.0.cmp(b.0));
        let mut rows: Vec<(&String, u16, u64)> = sorted
            .iter()
            .flat_map(|(route, r)| r.statuses.iter().map(move |&(st, n)| (*route, st, n)))
            .collect();
        rows.sort_unstable();
        for (route, status, n) in rows {
            let _ = writeln!(
                out,
                "terrastream_http_requests_total{{route=\"{}\",status=\"{status}\"}} {n}",
                esc(route)
            );
        }
        out.push_str("# HELP terrastream_http_request_duration_seconds Request latency by route.\n");
        out.push_str("# TYPE terrastream_http_request_duration_seconds histogram\n");
        for (route, stats) in &sorted {
            let (r, h) = (esc(route), &stats.latency);
            let mut cum = 0;
            for (b, c) in BUCKETS.iter().zip(h.counts) {
                cum += c;
                let _ = writeln!(
                    out,
                    "terrastream_http_request_duration_seconds_bucket{{route=\"{r}\",le=\"{b}\"}} {cum}"
                );
            }
            let _ = writeln!(
                out,
                "terrastream_http_request_duration_seconds_bucket{{route=\"{r}\",le=\"+Inf\"}} {}",
                h.count
            );
            let _ = writeln!(out, "terrastream_http_request_duration_seconds_sum{{route=\"{r}\"}} {}", h.sum);
            let _ =
                writeln!(out, "terrastream_http_request_duration_seconds_count{{route=\"{r}\"}} {}", h.count);
        }
        drop(routes);
        let mut scalar = |name: &str, kind: &str, help: &str, v: String| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {v}");
        };
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed).to_string();
        scalar("terrastream_http_response_bytes_total", "counter", "Body bytes sent.", get(&self.bytes_sent));
        scalar(
            "terrastream_cache_hits_total",
            "counter",
            "Blob requests served from memory.",
            get(&self.cache_hits),
        );
        scalar(
            "terrastream_cache_misses_total",
            "counter",
            "Blob requests read from disk.",
            get(&self.cache_misses),
        );
        scalar(
            "terrastream_corrupt_blobs_total",
            "counter",
            "Blobs that failed checksum verification (never sent).",
            get(&self.corrupt_blobs),
        );
        scalar(
            "terrastream_shed_requests_total",
            "counter",
            "Requests refused with 429/503.",
            get(&self.shed),
        );
        scalar(
            "terrastream_bake_queue_depth",
            "gauge",
            "On-demand bakes waiting for a worker.",
            self.bake_queue_depth.load(Ordering::Relaxed).to_string(),
        );
        scalar(
            "terrastream_bakes_running",
            "gauge",
            "On-demand bakes in progress.",
            self.bakes_running.load(Ordering::Relaxed).to_string(),
        );
        scalar(
            "terrastream_bakes_done_total",
            "counter",
            "On-demand node bakes completed.",
            get(&self.bakes_done),
        );
        scalar(
            "terrastream_bakes_failed_total",
            "counter",
            "On-demand node bakes failed.",
            get(&self.bakes_failed),
        );
        scalar(
            "terrastream_connections_open",
            "gauge",
            "TCP connections open.",
            self.connections_open.load(Ordering::Relaxed).to_string(),
        );
        scalar(
            "terrastream_connections_refused_total",
            "counter",
            "Connections refused (503, closed) because their client address was at --max-connections-per-client.",
            get(&self.connections_refused),
        );
        scalar(
            "terrastream_connections_idle_closed_total",
            "counter",
            "Connections closed after --idle-timeout with no request in flight.",
            get(&self.connections_idle_closed),
        );
        scalar(
            "terrastream_connections_header_timeouts_total",
            "counter",
            "Connections closed because a request head was not complete within --header-timeout.",
            get(&self.connections_header_timeouts),
        );
        scalar(
            "terrastream_connections_moved_total",
            "counter",
            "Connections a busy serving thread handed to a less busy one, at accept or between requests (serving threads pinned to CPUs, --cpu-affinity).",
            get(&self.connections_moved),
        );
        scalar(
            "terrastream_wire_answers_total",
            "counter",
            "Requests answered by the wire-level fast path in front of hyper (in-memory blobs and 3D Tiles GLBs); also in terrastream_http_requests_total.",
            get(&self.wire_answers),
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_cumulative_buckets() {
        let m = Metrics::default();
        m.record("/a", 200, Duration::from_millis(2));
        m.record("/a", 200, Duration::from_millis(20));
        m.record("/a", 404, Duration::from_secs(100));
        let t = m.render();
        assert!(t.contains("terrastream_http_requests_total{route=\"/a\",status=\"200\"} 2"), "{t}");
        assert!(t.contains("le=\"0.0025\"} 1"), "{t}");
        assert!(t.contains("le=\"0.025\"} 2"), "{t}");
        assert!(t.contains("le=\"10\"} 2"), "{t}");
        assert!(t.contains("le=\"+Inf\"} 3"), "{t}");
        assert_eq!(m.requests("/a", 404), 1);
    }
}
