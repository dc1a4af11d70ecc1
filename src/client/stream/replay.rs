//! Flight replay, the application `terrastream client` runs: drives a [`Session`] along a
//! camera [`Flight`] in real time ([`replay`]), renders its frames through a [`SessionView`]
//! (feature `gpu`), writes PNG frames and `stats.json` with the per-frame and total figures
//! ([`run_client`]).
//!
//! Frames are paced at `fps` and the flight advances `1/fps` per frame, so a slow frame delays
//! the flight instead of skipping poses.
//!
//! With a collision radius the ego is the flight's ego track at the frame's time, or, for a
//! flight without one, the camera's eye (its x, y: the point under the camera). Its look-ahead
//! distance is the farthest (horizontally) the ego gets from there within the next
//! `lookahead_s · speed` flight seconds (sampled at eight steps). Warm-up ends with the first
//! frame whose region is complete (no miss); `misses_after_warmup` counts the misses from that
//! frame on, and is `null` when no frame was complete.

use std::time::Duration;
#[cfg(feature = "gpu")]
use std::time::Instant;

use serde::Serialize;

use crate::client::ClientError;
use crate::client::stream::flight_path::Flight;
use crate::client::stream::session::{FrameStats, ReplayPhase, Session, SessionOptions};
#[cfg(feature = "gpu")]
use crate::client::stream::view::SessionView;
use glam::DVec3;

/// Frames per second of a replay (`--fps`).
pub const DEFAULT_FPS: f64 = 30.0;
/// Longest time a replay holds the last pose waiting for the view to complete (`--settle`).
pub const DEFAULT_SETTLE_S: f64 = 20.0;

/// Settings of a replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    pub fps: f64,
    /// Longest time to hold the last pose waiting for a complete view.
    pub settle_s: f64,
    /// Flight seconds per wall-clock second (tests fly faster than real time).
    pub speed: f64,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self { fps: DEFAULT_FPS, settle_s: DEFAULT_SETTLE_S, speed: 1.0 }
    }
}

/// Totals of a replay (`stats.json`'s `totals`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    pub frames: u32,
    pub flight_frames: u32,
    /// Response body bytes received, manifest included.
    pub bytes: u64,
    /// Requests started (retries count again), and how they ended.
    pub requests: u64,
    pub succeeded: u64,
    pub retries: u64,
    pub timeouts: u64,
    pub cancelled: u64,
    pub failed: u64,
    pub decode_errors: u64,
    /// Request latency (start to complete response) percentiles over successful requests (ms).
    pub latency_p50_ms: f64,
    pub latency_p99_ms: f64,
    /// Session time of the first frame whose view was complete (s); `null` if none was.
    pub first_complete_s: Option<f64>,
    /// Share of frames with tiles drawn and every drawn tile under the threshold.
    pub share_under_threshold: f64,
    /// The last frame was complete.
    pub settled: bool,
    pub select_ms_mean: f64,
    pub select_ms_max: f64,
    pub frame_ms_mean: f64,
    pub frame_ms_max: f64,
    pub render_ms_mean: f64,
    pub render_ms_max: f64,
    /// The collision region's totals (only with a collision radius).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub collision: Option<CollisionTotals>,
}

/// The collision region over a replay (`stats.json`'s `totals.collision`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CollisionTotals {
    pub radius_m: f64,
    pub lookahead_s: f64,
    /// Where the ego came from: `"flight"` (the flight's ego track) or `"camera"` (the eye).
    pub ego: String,
    /// Required nodes per frame: mean and most.
    pub required_mean: f64,
    pub required_max: u32,
    /// (frame, node) pairs where a required node was not resident at level 0 when drawn.
    pub misses: u64,
    /// The first frame whose region was complete (the end of warm-up); `null` if none was.
    pub warm_frame: Option<u32>,
    /// Its session time (s).
    pub warm_s: Option<f64>,
    /// Misses from the warm frame on; `null` when no frame was complete.
    pub misses_after_warmup: Option<u64>,
    /// Response body bytes received for resources the region asked for (level-0 leaf blobs
    /// and index chunks, whether or not the view wanted them too).
    pub bytes: u64,
    /// Distinct leaves the region asked for and that arrived at level 0.
    pub leaves_fetched: u64,
}

/// `stats.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    pub tileset: String,
    pub url: String,
    pub flight: Option<String>,
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub threshold_px: f64,
    pub fps: f64,
    /// The adapter frames were rendered on, or `off: <why>`.
    pub rendering: String,
    pub totals: Totals,
    pub frames: Vec<FrameStats>,
}

/// Percentile `p` (0..=1) of `v` by nearest rank; 0 for an empty slice.
#[must_use]
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = (p.clamp(0.0, 1.0) * s.len() as f64).ceil().max(1.0) as usize;
    s[rank.min(s.len()) - 1]
}

/// Flies `flight` (any frame; normalised keys are mapped onto the tileset's bounds) through a
/// session in real time, then holds the last pose until the view is complete or `settle_s` has
/// passed. `on_frame` sees the session after each frame (rendering hooks in there, adding its
/// time to the frame's `render_ms` and `frame_ms`).
pub fn replay(
    session: &mut Session,
    flight: &Flight,
    opts: &ReplayOptions,
    mut on_frame: impl FnMut(&Session, &mut FrameStats) -> Result<(), ClientError>,
) -> Result<(Vec<FrameStats>, Totals), ClientError> {
    if !(opts.fps.is_finite() && opts.fps > 0.0) {
        return Err(ClientError::Camera(format!("fps {} must be positive", opts.fps)));
    }
    if !(opts.speed.is_finite() && opts.speed > 0.0) {
        return Err(ClientError::Camera(format!("speed {} must be positive", opts.speed)));
    }
    let world = flight.to_world(&session.manifest().bounds).map_err(ClientError::FlightFrame)?;
    let lookahead = session.options().collision.map(|c| c.lookahead_s * opts.speed);
    let t0 = session.now();
    let mut frames = Vec::new();
    let mut settle_start = None;
    let mut i: u32 = 0;
    loop {
        let t = world.start() + f64::from(i) * opts.speed / opts.fps;
        let phase = if t <= world.end() { ReplayPhase::Flight } else { ReplayPhase::Settle };
        if phase == ReplayPhase::Settle {
            let since = *settle_start.get_or_insert(session.now());
            let last_complete =
                frames.last().is_some_and(|f: &FrameStats| f.complete && f.selection.retiring == 0);
            if last_complete || session.now() - since > opts.settle_s {
                break;
            }
        }
        let pose = world.pose_at(t);
        if let Some(ahead_s) = lookahead {
            let (ego, ahead_m) = ego_and_reach(&world, t, ahead_s);
            session.set_ego(ego, ahead_m)?;
        }
        let mut f = session.frame(&pose, t.min(world.end()), phase)?;
        on_frame(session, &mut f)?;
        frames.push(f);
        i += 1;
        let due = t0 + f64::from(i) / opts.fps;
        let wait = due - session.now();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
    }
    let mut totals = totals(session, &frames);
    totals.collision = session.options().collision.map(|c| CollisionTotals {
        radius_m: c.radius_m,
        lookahead_s: c.lookahead_s,
        ego: if world.has_ego() { "flight" } else { "camera" }.to_owned(),
        ..collision_totals(session, &frames)
    });
    Ok((frames, totals))
}

/// The ego at flight time `t` (its track, else the camera's eye) and the farthest it gets
/// horizontally within the next `ahead_s` flight seconds.
fn ego_and_reach(world: &Flight, t: f64, ahead_s: f64) -> (DVec3, f64) {
    let at = |t: f64| world.ego_at(t).unwrap_or_else(|| world.pose_at(t).eye);
    let ego = at(t);
    let reach =
        (1..=8).map(|i| (at(t + ahead_s * f64::from(i) / 8.0) - ego).truncate().length()).fold(0.0, f64::max);
    (ego, reach)
}

/// The collision figures of `frames` (radius, look-ahead and ego source left for the caller).
#[must_use]
pub fn collision_totals(session: &Session, frames: &[FrameStats]) -> CollisionTotals {
    let c: Vec<(&FrameStats, &crate::client::stream::session::CollisionFrame)> =
        frames.iter().filter_map(|f| f.collision.as_ref().map(|c| (f, c))).collect();
    let warm = c.iter().position(|(_, c)| c.misses == 0);
    let n = c.len().max(1) as f64;
    let asked = session.collision_asked();
    CollisionTotals {
        required_mean: c.iter().map(|(_, c)| f64::from(c.required)).sum::<f64>() / n,
        required_max: c.iter().map(|(_, c)| c.required).max().unwrap_or(0),
        misses: c.iter().map(|(_, c)| u64::from(c.misses)).sum(),
        warm_frame: warm.map(|i| c[i].0.frame),
        warm_s: warm.map(|i| c[i].0.wall_s),
        misses_after_warmup: warm.map(|i| c[i..].iter().map(|(_, c)| u64::from(c.misses)).sum()),
        bytes: session.collision_bytes(),
        leaves_fetched: session
            .fetch_counts()
            .keys()
            .filter(|r| {
                matches!(r, crate::client::stream::fetch::Resource::Tile { level: 0, .. })
                    && asked.contains(r)
            })
            .count() as u64,
        ..CollisionTotals::default()
    }
}

fn totals(session: &Session, frames: &[FrameStats]) -> Totals {
    let st = session.scheduler().stats();
    let n = frames.len().max(1) as f64;
    Totals {
        frames: frames.len() as u32,
        flight_frames: frames.iter().filter(|f| f.phase == ReplayPhase::Flight).count() as u32,
        bytes: session.bytes_received(),
        requests: st.started,
        succeeded: st.succeeded,
        retries: st.retries,
        timeouts: st.timeouts,
        cancelled: st.cancelled,
        failed: st.failed,
        decode_errors: session.decode_errors(),
        latency_p50_ms: percentile(&st.latencies_s, 0.5) * 1e3,
        latency_p99_ms: percentile(&st.latencies_s, 0.99) * 1e3,
        first_complete_s: frames.iter().find(|f| f.complete).map(|f| f.wall_s),
        share_under_threshold: frames.iter().filter(|f| f.selection.under_threshold).count() as f64 / n,
        settled: frames.last().is_some_and(|f| f.complete),
        select_ms_mean: frames.iter().map(|f| f.select_ms).sum::<f64>() / n,
        select_ms_max: frames.iter().map(|f| f.select_ms).fold(0.0, f64::max),
        frame_ms_mean: frames.iter().map(|f| f.frame_ms).sum::<f64>() / n,
        frame_ms_max: frames.iter().map(|f| f.frame_ms).fold(0.0, f64::max),
        render_ms_mean: frames.iter().map(|f| f.render_ms).sum::<f64>() / n,
        render_ms_max: frames.iter().map(|f| f.render_ms).fold(0.0, f64::max),
        collision: None,
    }
}

/// Name of the statistics file a replay writes into its output directory.
pub const STATS_FILE: &str = "stats.json";

/// The settled view's PNG, in the frames folder.
pub const FINAL_FRAME: &str = "final.png";
/// Folder under `--out` that PNG frames are written to.
pub const FRAMES_DIR: &str = "frames";
/// Every how many frames one is written as PNG (`--frames-every`; 0 = none). At 30 frames per
/// second this is three pictures per flight second, plus the settled view (`final.png`).
pub const DEFAULT_FRAMES_EVERY: u32 = 10;

/// Whether `terrastream client` renders (`--render`).
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RenderMode {
    /// With any adapter (software ones such as Mesa lavapipe included); without one, replays
    /// without rendering and says so.
    #[default]
    Auto,
    /// An adapter or a clear error.
    On,
    /// Selection and streaming only.
    Off,
}

/// Everything `terrastream client` needs.
#[derive(Debug, Clone)]
pub struct ClientRun {
    pub url: String,
    pub tileset: String,
    pub flight: std::path::PathBuf,
    pub out: std::path::PathBuf,
    pub session: SessionOptions,
    pub replay: ReplayOptions,
    pub render: RenderMode,
    /// Write every Nth frame as `OUT/frames/NNNNN.png` (0: none), and the settled view as
    /// `OUT/frames/final.png` (unless 0).
    pub frames_every: u32,
}

/// The renderer of a run, or why there is none.
#[cfg(feature = "gpu")]
fn open_view(
    mode: RenderMode,
    session: &Session,
    opts: &SessionOptions,
) -> Result<(Option<SessionView>, String), ClientError> {
    if mode == RenderMode::Off {
        return Ok((None, "off (--render off)".into()));
    }
    match crate::gpu::open() {
        Ok(ctx) => {
            let adapter = ctx.adapter.clone();
            let view = SessionView::new(ctx, session, opts.width, opts.height)?;
            Ok((Some(view), adapter))
        }
        Err(e) if mode == RenderMode::On => Err(e.into()),
        Err(e) => {
            tracing::warn!("not rendering: {e}");
            Ok((None, format!("off: {e}")))
        }
    }
}

/// Connects, replays the flight (rendering each frame unless `--render off` or no adapter under
/// `auto`), writes PNG frames and `OUT/stats.json`; `on_frame` sees every frame's figures
/// (progress output). Returns the report that was written.
pub fn run_client(
    run: &ClientRun,
    mut on_frame: impl FnMut(&FrameStats),
) -> Result<ReplayReport, ClientError> {
    let flight = Flight::load(&run.flight)?;
    let mut session = Session::connect(&run.url, &run.tileset, run.session)?;
    let io = |path: &std::path::Path| {
        let path = path.to_owned();
        move |source| ClientError::Io { path, source }
    };
    std::fs::create_dir_all(&run.out).map_err(io(&run.out))?;
    let frames_dir = run.out.join(FRAMES_DIR);
    #[cfg(feature = "gpu")]
    let (mut view, rendering) = open_view(run.render, &session, &run.session)?;
    #[cfg(not(feature = "gpu"))]
    let rendering = match run.render {
        RenderMode::On => {
            return Err(ClientError::NoGpuFeature);
        }
        _ => "off: built without the `gpu` feature".to_owned(),
    };
    #[cfg(feature = "gpu")]
    if view.is_some() && run.frames_every > 0 {
        std::fs::create_dir_all(&frames_dir).map_err(io(&frames_dir))?;
    }
    let (frames, totals) = replay(&mut session, &flight, &run.replay, |s, f| {
        #[cfg(feature = "gpu")]
        if let Some(v) = view.as_mut() {
            let write = run.frames_every > 0 && f.frame % run.frames_every == 0;
            let start = Instant::now();
            let img = v.draw(s, write)?;
            f.render_ms = start.elapsed().as_secs_f64() * 1e3;
            f.frame_ms += f.render_ms;
            if let Some(img) = img {
                let start = Instant::now();
                let path = frames_dir.join(format!("{:05}.png", f.frame));
                crate::client::render::Renderer::save_png(&img, &path)?;
                f.write_ms = start.elapsed().as_secs_f64() * 1e3;
            }
        }
        #[cfg(not(feature = "gpu"))]
        let _ = (s, &frames_dir);
        on_frame(f);
        Ok(())
    })?;
    #[cfg(feature = "gpu")]
    if let (Some(v), true) = (view.as_mut(), run.frames_every > 0)
        && let Some(img) = v.draw(&session, true)?
    {
        crate::client::render::Renderer::save_png(&img, &frames_dir.join(FINAL_FRAME))?;
    }
    let report = ReplayReport {
        tileset: run.tileset.clone(),
        url: run.url.clone(),
        flight: flight.name.clone(),
        width: run.session.width,
        height: run.session.height,
        fov_deg: run.session.fov_deg,
        threshold_px: run.session.select.threshold_px,
        fps: run.replay.fps,
        rendering,
        totals,
        frames,
    };
    let path = run.out.join(STATS_FILE);
    let json = serde_json::to_vec_pretty(&report)
        .map_err(|e| ClientError::Io { path: path.clone(), source: std::io::Error::other(e) })?;
    crate::store::write_atomic(&path, &json)
        .map_err(|e| ClientError::Io { path: path.clone(), source: std::io::Error::other(e.to_string()) })?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert!((percentile(&v, 0.5) - 50.0).abs() < 1e-12);
        assert!((percentile(&v, 0.99) - 99.0).abs() < 1e-12);
        assert!((percentile(&[3.0], 0.99) - 3.0).abs() < 1e-12);
        assert!(percentile(&[], 0.5).abs() < 1e-12);
    }
}
