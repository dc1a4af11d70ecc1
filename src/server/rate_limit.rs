//! The per-client rate limit (`--rate-limit`): a token bucket per client address.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Per-client token buckets (requests per second, bursts of twice that).
pub struct RateLimiter {
    rate: f64,
    buckets: Mutex<HashMap<IpAddr, (f64, Instant)>>,
}

impl RateLimiter {
    pub fn new(rate: u32) -> Self {
        Self { rate: f64::from(rate), buckets: Mutex::new(HashMap::new()) }
    }

    /// Is there a limit at all?
    pub fn enabled(&self) -> bool {
        self.rate > 0.0
    }

    /// `None` when the request may go ahead, else seconds to wait.
    pub(super) fn check(&self, ip: IpAddr) -> Option<u32> {
        if self.rate <= 0.0 {
            return None;
        }
        let now = Instant::now();
        let burst = self.rate * 2.0;
        let mut b = self.buckets.lock().ok()?;
        if b.len() > 100_000 {
            // Forget clients idle long enough to have refilled: bounded memory under many IPs.
            let horizon = Duration::from_secs_f64(burst / self.rate + 1.0);
            b.retain(|_, (_, t)| now.duration_since(*t) < horizon);
        }
        let (tokens, last) = b.entry(ip).or_insert((burst, now));
        *tokens = (*tokens + now.duration_since(*last).as_secs_f64() * self.rate).min(burst);
        *last = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            None
        } else {
            Some(((1.0 - *tokens) / self.rate).ceil().max(1.0) as u32)
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn rate_limiter_bursts_then_refuses() {
        let r = RateLimiter::new(2);
        let ip: IpAddr = "10.0.0.1".parse().unwrap();
        assert!((0..4).all(|_| r.check(ip).is_none()));
        assert!(r.check(ip).is_some());
        assert!(RateLimiter::new(0).check(ip).is_none());
    }
}
