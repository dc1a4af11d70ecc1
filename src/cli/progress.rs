//! The bake progress bar (with `--time-limit`) and the peak-memory figure of the summaries.

use std::time::{Duration, Instant};

use indicatif::ProgressBar;
use terrastream::bake;

/// A progress bar and, with `--time-limit`, when the bake started and how long it may run.
pub struct Bar(pub ProgressBar, pub Option<(Instant, Duration)>);

impl bake::Progress for Bar {
    fn start(&self, total: u64, resumed: u64) {
        self.0.set_length(total);
        self.0.set_position(resumed);
        self.0.reset_eta();
        if resumed > 0 {
            self.0.println(format!("resuming: {resumed} of {total} tiles already baked"));
        }
    }
    fn node_done(&self) {
        self.0.inc(1);
    }
    fn cancelled(&self) -> Option<String> {
        let (t0, limit) = self.1?;
        (t0.elapsed() > limit).then(|| {
            format!(
                "--time-limit of {} s passed; the tiles baked so far are kept, run again to resume",
                limit.as_secs_f64()
            )
        })
    }
}

/// The process's peak resident memory, where the OS reports it (Linux).
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}
