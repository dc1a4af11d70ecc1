//! The progress bars of the commands (bake tiles, scans, the demo bake; with `--time-limit`)
//! and the peak-memory figure of the summaries.
//!
//! A bar stays hidden until it knows its length ([`Bar::show`], called by
//! [`bake::Progress::start`]): a bar drawn before that shows a full `0/0`, and a line printed
//! meanwhile (a notice) leaves that drawing behind on the terminal.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use terrastream::bake;

/// The template of a bake's tiles bar.
pub const TILES_TEMPLATE: &str = "{bar:40} {pos}/{len} tiles  {per_sec}  ETA {eta}  {elapsed}";

/// A progress bar, hidden until it is shown, and, with `--time-limit`, when the bake started
/// and how long it may run.
pub struct Bar {
    inner: ProgressBar,
    /// Where the bar draws once shown (`None` once shown, or for a quiet bar).
    target: Mutex<Option<ProgressDrawTarget>>,
    limit: Option<(Instant, Duration)>,
}

impl Bar {
    /// A bar that will draw to `target` once shown, in `template`'s style.
    pub fn new(template: &str, target: ProgressDrawTarget, time_limit: Option<f64>) -> Self {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::hidden());
        bar.set_style(
            ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        Self {
            inner: bar,
            target: Mutex::new(Some(target)),
            limit: time_limit.map(|s| (Instant::now(), Duration::from_secs_f64(s))),
        }
    }

    /// A bar on stderr, or none at all with `quiet`.
    pub fn stderr(template: &str, quiet: bool, time_limit: Option<f64>) -> Self {
        let target = if quiet { ProgressDrawTarget::hidden() } else { ProgressDrawTarget::stderr() };
        Self::new(template, target, time_limit)
    }

    /// Starts drawing (once; later calls do nothing).
    pub fn show(&self) {
        let target = self.target.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take();
        if let Some(t) = target {
            self.inner.set_draw_target(t);
            self.inner.enable_steady_tick(Duration::from_millis(200));
        }
    }

    pub fn bar(&self) -> &ProgressBar {
        &self.inner
    }

    /// Removes the bar from the terminal.
    pub fn finish(&self) {
        self.inner.finish_and_clear();
    }
}

impl bake::Progress for Bar {
    fn start(&self, total: u64, resumed: u64) {
        self.inner.set_length(total);
        self.inner.set_position(resumed);
        self.inner.reset_eta();
        self.show();
        if resumed > 0 {
            self.inner.println(format!("resuming: {resumed} of {total} tiles already baked"));
        }
    }
    fn node_done(&self) {
        self.inner.inc(1);
    }
    fn cancelled(&self) -> Option<String> {
        let (t0, limit) = self.limit?;
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

#[cfg(test)]
mod tests {
    use std::io;
    use std::sync::{Arc, Mutex};

    use indicatif::{ProgressDrawTarget, TermLike};
    use terrastream::bake::Progress as _;

    use super::{Bar, TILES_TEMPLATE};

    /// A terminal that records what is drawn on it.
    #[derive(Debug, Clone, Default)]
    struct Tape(Arc<Mutex<String>>);

    impl Tape {
        fn text(&self) -> String {
            self.0.lock().unwrap().clone()
        }
    }

    impl TermLike for Tape {
        fn width(&self) -> u16 {
            120
        }
        fn move_cursor_up(&self, _: usize) -> io::Result<()> {
            Ok(())
        }
        fn move_cursor_down(&self, _: usize) -> io::Result<()> {
            Ok(())
        }
        fn move_cursor_right(&self, _: usize) -> io::Result<()> {
            Ok(())
        }
        fn move_cursor_left(&self, _: usize) -> io::Result<()> {
            Ok(())
        }
        fn write_line(&self, s: &str) -> io::Result<()> {
            let mut t = self.0.lock().unwrap();
            t.push_str(s);
            t.push('\n');
            Ok(())
        }
        fn write_str(&self, s: &str) -> io::Result<()> {
            self.0.lock().unwrap().push_str(s);
            Ok(())
        }
        fn clear_line(&self) -> io::Result<()> {
            Ok(())
        }
        fn flush(&self) -> io::Result<()> {
            Ok(())
        }
    }

    /// Before the bake knows its tiles (opening the inputs, the point baker, printing notices),
    /// nothing is drawn: no full `0/0 tiles` bar is left behind on the terminal.
    #[test]
    fn the_tiles_bar_draws_nothing_before_the_bake_starts() {
        let tape = Tape::default();
        let bar = Bar::new(TILES_TEMPLATE, ProgressDrawTarget::term_like(Box::new(tape.clone())), None);
        bar.bar().force_draw();
        bar.bar().println("a notice printed before the bake");
        std::thread::sleep(std::time::Duration::from_millis(450));
        assert!(!tape.text().contains("tiles"), "drawn before the start: {:?}", tape.text());
        bar.start(8, 0);
        bar.node_done();
        bar.bar().force_draw();
        assert!(tape.text().contains("1/8 tiles"), "{:?}", tape.text());
        assert!(!tape.text().contains("0/0"), "{:?}", tape.text());
        bar.finish();
    }

    /// A quiet bar never draws.
    #[test]
    fn a_quiet_bar_draws_nothing() {
        let bar = Bar::stderr(TILES_TEMPLATE, true, None);
        bar.start(8, 0);
        assert!(bar.bar().is_hidden());
    }
}
