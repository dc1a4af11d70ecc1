//! `terrastream client`: replay a camera flight against a running server.

use std::path::PathBuf;

use anyhow::Result;
use terrastream::client;

#[derive(clap::Args)]
pub struct ClientArgs {
    /// Server base URL (http://HOST:PORT[/PREFIX]).
    #[arg(long)]
    pub url: String,
    /// Tileset name on the server.
    #[arg(long)]
    pub tileset: String,
    /// Flight JSON (timestamped eye/target/up keys; see docs: world or normalized frame).
    #[arg(long)]
    pub flight: PathBuf,
    /// Viewport width in pixels.
    #[arg(long, default_value_t = client::stream::session::DEFAULT_WIDTH)]
    pub width: u32,
    /// Viewport height in pixels.
    #[arg(long, default_value_t = client::stream::session::DEFAULT_HEIGHT)]
    pub height: u32,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = client::select::DEFAULT_FOV_DEG)]
    pub fov: f64,
    /// Screen-space error threshold in pixels.
    #[arg(long, default_value_t = client::select::DEFAULT_THRESHOLD_PX)]
    pub threshold: f64,
    /// Level cross-fade duration in seconds (0: switch at once).
    #[arg(long, default_value_t = client::select::DEFAULT_FADE_SECONDS)]
    pub fade: f64,
    /// Frames per second of the replay.
    #[arg(long, default_value_t = client::stream::replay::DEFAULT_FPS)]
    pub fps: f64,
    /// Longest time (s) to hold the last pose waiting for a complete view.
    #[arg(long, default_value_t = client::stream::replay::DEFAULT_SETTLE_S)]
    pub settle: f64,
    /// Requests running at once.
    #[arg(long, default_value_t = client::stream::fetch::DEFAULT_MAX_IN_FLIGHT)]
    pub max_in_flight: usize,
    /// Decoded-tile cache budget in MiB.
    #[arg(long, default_value_t = client::stream::fetch::DEFAULT_CACHE_BYTES >> 20)]
    pub cache_mb: usize,
    /// Render frames (wgpu, headless): auto = with any adapter (software included), replaying
    /// without rendering when there is none; on = an adapter or an error; off = never.
    #[arg(long, value_enum, default_value = "auto")]
    pub render: client::stream::replay::RenderMode,
    /// Write every Nth rendered frame as OUT/frames/NNNNN.png plus the settled view as
    /// OUT/frames/final.png; 0 = write none (frames are still rendered and timed).
    #[arg(long, default_value_t = client::stream::replay::DEFAULT_FRAMES_EVERY)]
    pub frames_every: u32,
    /// Collision region: keep every leaf within this horizontal distance (world units, metres)
    /// of the ego at full detail (level 0), fetched ahead of the view and never evicted while
    /// inside. The ego is the flight's ego track, or the camera's eye for a flight without one.
    #[arg(long, value_name = "R")]
    pub collision_radius: Option<f64>,
    /// Seconds of ego motion whose leaves are fetched before they enter the collision region.
    #[arg(long, default_value_t = client::collision::DEFAULT_LOOKAHEAD_S, requires = "collision_radius")]
    pub collision_lookahead: f64,
    /// Output directory (stats.json, frames/).
    #[arg(long, default_value = "out/client")]
    pub out: PathBuf,
}

pub fn run(a: &ClientArgs, quiet: bool) -> Result<()> {
    use client::stream::replay::{ClientRun, ReplayOptions};
    use client::stream::session::SessionOptions;
    let defaults = SessionOptions::default();
    let collision = a
        .collision_radius
        .map(|r| client::collision::CollisionParams::new(r, a.collision_lookahead))
        .transpose()?;
    let run = ClientRun {
        url: a.url.clone(),
        tileset: a.tileset.clone(),
        flight: a.flight.clone(),
        out: a.out.clone(),
        session: SessionOptions {
            width: a.width,
            height: a.height,
            fov_deg: a.fov,
            select: client::select::SelectParams {
                threshold_px: a.threshold,
                fade_seconds: a.fade,
                ..defaults.select
            },
            fetch: client::stream::fetch::FetchParams { max_in_flight: a.max_in_flight, ..defaults.fetch },
            cache_bytes: a.cache_mb.saturating_mul(1 << 20),
            collision,
        },
        replay: ReplayOptions { fps: a.fps, settle_s: a.settle, speed: 1.0 },
        render: a.render,
        frames_every: a.frames_every,
    };
    let report = client::stream::replay::run_client(&run, |f| {
        if !quiet && f.frame % 30 == 0 {
            eprintln!(
                "frame {:>5} t {:>6.2}s {:<6} drawn {:?} in flight {:>2} select {:.3} ms frame {:.1} ms",
                f.frame,
                f.t,
                f.phase,
                f.selection.drawn_per_level,
                f.requests_in_flight,
                f.select_ms,
                f.frame_ms
            );
        }
    })?;
    let t = &report.totals;
    outln!(
        "{} frames ({} in flight), {} bytes in {} requests ({} retries, {} failed), latency p50 {:.1} ms p99 {:.1} ms",
        t.frames,
        t.flight_frames,
        t.bytes,
        t.requests,
        t.retries,
        t.failed,
        t.latency_p50_ms,
        t.latency_p99_ms
    );
    outln!(
        "first complete view {}, frames under {} px: {:.1} %, settled: {}, selection mean {:.3} ms max {:.3} ms",
        t.first_complete_s.map_or_else(|| "never".to_owned(), |s| format!("at {s:.2} s")),
        report.threshold_px,
        100.0 * t.share_under_threshold,
        t.settled,
        t.select_ms_mean,
        t.select_ms_max
    );
    outln!(
        "rendering: {}{}",
        report.rendering,
        if t.render_ms_mean > 0.0 {
            format!(" — render mean {:.2} ms max {:.2} ms per frame", t.render_ms_mean, t.render_ms_max)
        } else {
            String::new()
        }
    );
    if let Some(c) = &t.collision {
        outln!(
            "collision region {} m (ego from the {}): {:.1} nodes required per frame (max {}), {} misses, {} after warm-up ({}), {} leaves fetched, {} bytes",
            c.radius_m,
            c.ego,
            c.required_mean,
            c.required_max,
            c.misses,
            c.misses_after_warmup.map_or_else(|| "n/a".to_owned(), |m| m.to_string()),
            match (c.warm_frame, c.warm_s) {
                (Some(f), Some(s)) => format!("complete from frame {f} at {s:.2} s"),
                _ => "never complete".to_owned(),
            },
            c.leaves_fetched,
            c.bytes
        );
    }
    let frames = a.out.join(client::stream::replay::FRAMES_DIR);
    if frames.is_dir() {
        outln!("wrote frames to {}", frames.display());
    }
    outln!("wrote {}", a.out.join(client::stream::replay::STATS_FILE).display());
    Ok(())
}
