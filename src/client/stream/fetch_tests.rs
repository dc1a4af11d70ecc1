use std::time::{Duration, SystemTime};

use proptest::prelude::*;

use super::*;

#[derive(Default)]
struct Recorder {
    started: Vec<(RequestId, Resource)>,
    cancelled: Vec<RequestId>,
}

impl Transport for Recorder {
    fn start(&mut self, id: RequestId, resource: Resource) {
        self.started.push((id, resource));
    }
    fn cancel(&mut self, id: RequestId) {
        self.cancelled.push(id);
    }
}

fn tile(x: u32) -> Resource {
    Resource::Tile { key: TileKey::new(3, x, 0), level: 0 }
}

fn pri(visible: bool, error_px: f64) -> Priority {
    Priority { visible, error_px, collision: false }
}

fn params(max_in_flight: usize) -> FetchParams {
    FetchParams { max_in_flight, ..FetchParams::default() }
}

#[test]
fn priority_order_and_concurrency_limit() {
    let mut s = Scheduler::new(params(2));
    let mut t = Recorder::default();
    s.update(
        &[
            (tile(0), pri(false, 100.0)),
            (tile(1), pri(true, 3.0)),
            (tile(2), pri(true, f64::INFINITY)),
            (tile(3), pri(true, 10.0)),
        ],
        0.0,
    );
    s.pump(0.0, &mut t);
    assert_eq!(t.started.iter().map(|x| x.1).collect::<Vec<_>>(), vec![tile(2), tile(3)]);
    assert_eq!(s.in_flight(), 2);
    s.pump(0.1, &mut t);
    assert_eq!(t.started.len(), 2, "limit holds");
    assert_eq!(
        s.complete(t.started[0].0, &Outcome::Ok { bytes: 10 }, 0.2),
        Some(Finished { resource: tile(2), ok: true })
    );
    s.update(&[(tile(0), pri(false, 100.0)), (tile(1), pri(true, 3.0)), (tile(3), pri(true, 10.0))], 0.2);
    s.pump(0.2, &mut t);
    assert_eq!(t.started[2].1, tile(1), "visible before invisible");
    assert_eq!(s.stats().bytes, 10);
    assert!((s.stats().latencies_s[0] - 0.2).abs() < 1e-12);
    // A late duplicate result is ignored.
    assert_eq!(s.complete(t.started[0].0, &Outcome::Ok { bytes: 10 }, 0.3), None);
}

#[test]
fn collision_region_wants_go_first() {
    let mut s = Scheduler::new(params(2));
    let mut t = Recorder::default();
    let region = |error_px| Priority { collision: true, visible: false, error_px };
    s.update(
        &[
            (tile(0), pri(true, f64::INFINITY)),
            (tile(1), region(1.0)),
            (tile(2), pri(true, 50.0)),
            (tile(3), region(5.0)),
        ],
        0.0,
    );
    s.pump(0.0, &mut t);
    assert_eq!(t.started.iter().map(|x| x.1).collect::<Vec<_>>(), vec![tile(3), tile(1)]);
    // The view's hole goes next, before its 50 px tile.
    s.complete(t.started[0].0, &Outcome::Ok { bytes: 1 }, 0.1);
    s.update(&[(tile(0), pri(true, f64::INFINITY)), (tile(1), region(1.0)), (tile(2), pri(true, 50.0))], 0.1);
    s.pump(0.1, &mut t);
    assert_eq!(t.started[2].1, tile(0));
}

#[test]
fn unwanted_requests_are_cancelled_after_grace() {
    let mut s = Scheduler::new(params(4));
    let mut t = Recorder::default();
    s.update(&[(tile(0), pri(true, 5.0)), (tile(1), pri(true, 4.0))], 0.0);
    s.pump(0.0, &mut t);
    s.update(&[(tile(1), pri(true, 4.0))], 0.1);
    s.pump(0.1, &mut t);
    assert!(t.cancelled.is_empty(), "within the grace");
    s.update(&[(tile(1), pri(true, 4.0))], 1.0);
    s.pump(1.0, &mut t);
    assert_eq!(t.cancelled, vec![t.started[0].0]);
    assert_eq!(s.stats().cancelled, 1);
    assert_eq!(s.in_flight(), 1);
    assert_eq!(s.complete(t.started[0].0, &Outcome::Ok { bytes: 5 }, 1.1), None, "cancelled result ignored");
    // Wanted again within the grace: not cancelled.
    s.update(&[], 2.0);
    s.update(&[(tile(1), pri(true, 4.0))], 2.3);
    s.pump(2.3, &mut t);
    assert_eq!(t.cancelled.len(), 1);
}

#[test]
fn timeouts_and_5xx_back_off_exponentially() {
    let p = FetchParams {
        max_in_flight: 1,
        timeout_s: 1.0,
        backoff_base_s: 0.5,
        backoff_max_s: 4.0,
        ..FetchParams::default()
    };
    let mut s = Scheduler::new(p);
    let mut t = Recorder::default();
    let want = [(tile(0), pri(true, 5.0))];
    s.update(&want, 0.0);
    s.pump(0.0, &mut t);
    // Times out in pump.
    s.update(&want, 1.0);
    s.pump(1.0, &mut t);
    assert_eq!(t.cancelled, vec![1]);
    assert_eq!(s.stats().timeouts, 1);
    let d1 = backoff_delay(&p, &tile(0), 1);
    assert!((0.25..=0.5).contains(&d1), "{d1}");
    assert_eq!(s.next_deadline(1.0), Some(1.0 + d1));
    s.update(&want, 1.0 + d1 * 0.99);
    s.pump(1.0 + d1 * 0.99, &mut t);
    assert_eq!(t.started.len(), 1, "not before the backoff");
    let now = 1.0 + d1;
    s.update(&want, now);
    s.pump(now, &mut t);
    assert_eq!(t.started.len(), 2);
    // A 503 without Retry-After: second failure, longer delay.
    assert_eq!(s.complete(2, &Outcome::Status { code: 503, retry_after_s: None }, now), None);
    let d2 = backoff_delay(&p, &tile(0), 2);
    assert!((0.5..=1.0).contains(&d2), "{d2}");
    assert_eq!(s.next_deadline(now), Some(now + d2));
    for k in 1..20 {
        let d = backoff_delay(&p, &tile(0), k);
        let full = (0.5 * 2f64.powi(k as i32 - 1)).min(4.0);
        assert!(d >= full / 2.0 && d <= full, "attempt {k}: {d}");
    }
    // A network error retries too, a 404 fails for good.
    s.update(&want, now + d2);
    s.pump(now + d2, &mut t);
    assert_eq!(s.complete(3, &Outcome::Network("refused".into()), now + d2), None);
    assert_eq!(s.stats().retries, 3);
    let mut s = Scheduler::new(p);
    s.update(&want, 0.0);
    s.pump(0.0, &mut t);
    let id = t.started.last().unwrap().0;
    assert_eq!(
        s.complete(id, &Outcome::Status { code: 404, retry_after_s: None }, 0.1),
        Some(Finished { resource: tile(0), ok: false })
    );
    assert_eq!(s.failure(&tile(0)), Some(404));
    s.update(&want, 10.0);
    s.pump(10.0, &mut t);
    assert_eq!(s.in_flight(), 0, "a permanent failure is not retried");
}

#[test]
fn retry_after_pauses_everything() {
    let mut s = Scheduler::new(params(4));
    let mut t = Recorder::default();
    let want = [(tile(0), pri(true, 5.0)), (tile(1), pri(true, 4.0))];
    s.update(&want, 0.0);
    s.pump(0.0, &mut t);
    assert_eq!(s.complete(1, &Outcome::Status { code: 503, retry_after_s: Some(7.0) }, 0.5), None);
    assert!(s.paused(0.6));
    assert_eq!(s.complete(2, &Outcome::Ok { bytes: 1 }, 0.6).map(|f| f.ok), Some(true));
    s.update(&[(tile(0), pri(true, 5.0)), (tile(5), pri(true, 1.0))], 3.0);
    s.pump(3.0, &mut t);
    assert_eq!(t.started.len(), 2, "nothing new starts while the server asked to wait");
    s.update(&[(tile(0), pri(true, 5.0)), (tile(5), pri(true, 1.0))], 7.49);
    s.pump(7.49, &mut t);
    assert_eq!(t.started.len(), 2);
    s.update(&[(tile(0), pri(true, 5.0)), (tile(5), pri(true, 1.0))], 7.5);
    s.pump(7.5, &mut t);
    assert_eq!(t.started[2..].iter().map(|x| x.1).collect::<Vec<_>>(), vec![tile(0), tile(5)]);
    // Absurd values are clamped.
    s.complete(3, &Outcome::Status { code: 429, retry_after_s: Some(1e9) }, 8.0);
    assert!(s.paused(8.0 + MAX_RETRY_AFTER_S - 1.0) && !s.paused(8.0 + MAX_RETRY_AFTER_S));
}

#[test]
fn retry_after_header_values() {
    let now = SystemTime::UNIX_EPOCH + Duration::from_secs(784_111_777); // Sun, 06 Nov 1994 08:49:37 GMT
    assert_eq!(parse_retry_after("120", now), Some(120.0));
    assert_eq!(parse_retry_after(" 0 ", now), Some(0.0));
    assert_eq!(parse_retry_after("Sun, 06 Nov 1994 08:51:37 GMT", now), Some(120.0));
    assert_eq!(parse_retry_after("Sun, 06 Nov 1994 08:00:00 GMT", now), Some(0.0), "past dates mean now");
    assert_eq!(parse_retry_after("Thu, 01 Jan 1970 00:00:00 GMT", SystemTime::UNIX_EPOCH), Some(0.0));
    assert_eq!(
        parse_retry_after("Sat, 29 Feb 2020 12:00:00 GMT", SystemTime::UNIX_EPOCH),
        Some(1_582_977_600.0)
    );
    // The obsolete forms RFC 9110 §5.6.7 says a recipient must accept.
    assert_eq!(parse_retry_after("Sunday, 06-Nov-94 08:51:37 GMT", now), Some(120.0));
    assert_eq!(parse_retry_after("Sun Nov  6 08:51:37 1994", now), Some(120.0));
    for bad in [
        "",
        "-5",
        "1.5",
        "soon",
        "Sun, 06 Nov 1994 08:49:37 CET",
        "Sun, 06 Foo 1994 08:49:37 GMT",
        "Sun, 06 Nov 1994 25:49:37 GMT",
        "Sun, 06 Nov 1994 08:60:37 GMT",
        "Wed, 30 Feb 2000 00:00:00 GMT",
        "Mon, 06 Nov 1994 08:49:37 GMT",
        "Sun, 06 Nov 1994 08:49:37",
        "Thu, 31 Dec 1969 23:59:59 GMT",
    ] {
        assert_eq!(parse_retry_after(bad, now), None, "{bad:?}");
    }
    assert!(retryable(500) && retryable(503) && retryable(429) && retryable(408));
    assert!(!retryable(404) && !retryable(400) && !retryable(200));
}

#[test]
fn wants_put_chunks_first() {
    let w = Want { node: 0, key: TileKey::new(1, 0, 0), level: 2, priority_px: 3.0 };
    let v = wants_of(&[w], &[TileKey::new(4, 1, 1)]);
    assert_eq!(v[0].0, Resource::Chunk { root: TileKey::new(4, 1, 1) });
    assert_eq!(v[0].0.path(), "index/4/1/1.json");
    assert_eq!(v[1].0.path(), "tiles/1/0/0/2.tsb");
}

#[test]
fn cache_is_lru_within_budget() {
    let mut c: TileCache<u32> = TileCache::new(100);
    let k = |x| TileKey::new(2, x, 0);
    assert!(c.insert(k(0), 0, 0, 40).is_empty());
    assert!(c.insert(k(1), 0, 1, 40).is_empty());
    assert_eq!(c.get(k(0), 0), Some(&0));
    // k(1) is least recently used.
    assert_eq!(c.insert(k(2), 1, 2, 40), vec![(k(1), 0)]);
    assert_eq!(c.used_bytes(), 80);
    assert_eq!(c.levels(k(2)), 0b10);
    assert_eq!(c.levels(k(1)), 0);
    // Replacing an entry does not double count.
    c.insert(k(2), 1, 3, 30);
    assert_eq!(c.used_bytes(), 70);
    assert_eq!(c.peek(k(2), 1), Some(&3));
    // A tile larger than the budget is still kept for this frame.
    let ev = c.insert(k(3), 0, 4, 500);
    assert_eq!(ev.len(), 2);
    assert!(c.contains(k(3), 0));
    // Not drawn: evicted on the next frame's pin update.
    assert_eq!(c.set_drawn([]), vec![(k(3), 0)]);
    assert_eq!(c.evictions(), 4);
}

#[test]
fn cache_never_evicts_drawn_tiles() {
    let mut c: TileCache<()> = TileCache::new(100);
    let k = |x| TileKey::new(2, x, 0);
    c.insert(k(0), 0, (), 60);
    c.insert(k(1), 0, (), 40);
    c.set_drawn([(k(0), 0), (k(1), 0)]);
    // Over budget, but both are drawn: the newcomer stays too, nothing is evicted.
    assert!(c.insert(k(2), 0, (), 50).is_empty());
    assert_eq!(c.used_bytes(), 150);
    assert_eq!(c.set_drawn([(k(0), 0), (k(1), 0)]), vec![(k(2), 0)]);
}

#[test]
fn held_tiles_stay_even_when_they_arrive_later() {
    let mut c: TileCache<()> = TileCache::new(10);
    let k = |x| TileKey::new(2, x, 0);
    // Held before either arrives; both arrive in one batch of replies.
    c.set_held([(k(0), 0), (k(1), 0)]);
    c.insert(k(0), 0, (), 30);
    assert!(c.insert(k(1), 0, (), 30).is_empty());
    // An unheld newcomer is kept only until the next insert.
    c.insert(k(2), 0, (), 30);
    assert_eq!(c.insert(k(3), 0, (), 30), vec![(k(2), 0)]);
    assert!(c.contains(k(0), 0) && c.contains(k(1), 0) && c.contains(k(3), 0));
    // No longer held: evicted down to the budget.
    assert_eq!(c.set_held([(k(1), 0)]).len(), 2);
    assert!(c.contains(k(1), 0) && !c.contains(k(0), 0));
}

proptest! {
    #[test]
    fn cache_pins_hold_under_random_traffic(ops in prop::collection::vec((0u32..40, 0u8..3, 1usize..60, prop::collection::vec((0u32..40, 0u8..3), 0..8)), 1..200)) {
        let mut c: TileCache<u32> = TileCache::new(300);
        let mut drawn: Vec<(TileKey, u8)> = Vec::new();
        for (x, l, bytes, next_drawn) in ops {
            let ev = c.insert(TileKey::new(5, x, 0), l, x, bytes);
            for e in &ev {
                prop_assert!(!drawn.contains(e), "evicted a drawn tile {:?}", e);
            }
            let next: Vec<(TileKey, u8)> = next_drawn.into_iter().map(|(x, l)| (TileKey::new(5, x, 0), l)).filter(|(k, l)| c.contains(*k, *l)).collect();
            let ev = c.set_drawn(next.iter().copied());
            for e in &ev {
                prop_assert!(!next.contains(e), "evicted a drawn tile {:?}", e);
            }
            drawn = next;
            let pinned_bytes: usize = drawn.len() * 60;
            prop_assert!(c.used_bytes() <= 300 + pinned_bytes + 60);
            let recount: usize = (0..40).flat_map(|x| (0..3).map(move |l| (x, l))).filter(|&(x, l)| c.contains(TileKey::new(5, x, 0), l)).count();
            prop_assert_eq!(recount, c.len());
        }
    }
}
