//! What a flight over a tileset costs with everything resident (`terrastream eval --flight`):
//! per frame the primitives (mesh vertices and points) and bytes the selection draws, the bytes
//! a client streams over the whole flight (each (tile, level) it ever draws, once), and whether
//! every view is complete and under the threshold. Pure: the tree's index figures, the selector
//! and the flight's poses; nothing is fetched or rendered, so two tilesets (or two bakes of one
//! raster) compare exactly, frame by frame, without the timing noise of a live stream.

use std::collections::HashSet;

use serde::Serialize;

use crate::client::ClientError;
use crate::client::camera::Camera;
use crate::client::select::{AllResident, SelectParams, Selector};
use crate::client::stream::flight_path::{Flight, FlightError};
use crate::client::tree::{LevelCost, TileTree};
use crate::geom::Bounds;
use crate::tiling::TileKey;

/// Most frames one flight is sampled at (a flight of hours at 30 fps is cut to this many
/// evenly spaced poses rather than looping without bound).
pub const MAX_FLIGHT_FRAMES: usize = 100_000;

/// One frame of a flight.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameCost {
    pub t: f64,
    pub draws: u32,
    /// Mesh vertices plus points drawn (what the GPU transforms).
    pub primitives: u64,
    /// Bytes of the blobs drawn.
    pub bytes: u64,
    /// Largest screen-space error drawn, pixels.
    pub max_error_px: f64,
}

/// A flight's cost: per frame and in total.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlightCost {
    pub flight: String,
    pub rule: Rule,
    pub fps: f64,
    pub threshold_px: f64,
    pub width: u32,
    pub height: u32,
    pub frames: Vec<FrameCost>,
    /// Bytes of every distinct (tile, level) drawn during the flight: what a client with a
    /// large enough cache streams.
    pub streamed_bytes: u64,
    pub streamed_blobs: u64,
    /// Draws per level id, summed over the frames.
    pub draws_per_level: Vec<u64>,
    /// Frames where some visible node drew a level over the threshold other than a leaf's
    /// finest (which cannot do better): 0 means every view was under the threshold.
    pub frames_over_threshold: u32,
}

impl FlightCost {
    /// Mean primitives and bytes drawn per frame.
    #[must_use]
    pub fn mean_per_frame(&self) -> (f64, f64) {
        let n = self.frames.len().max(1) as f64;
        let p: u64 = self.frames.iter().map(|f| f.primitives).sum();
        let b: u64 = self.frames.iter().map(|f| f.bytes).sum();
        (p as f64 / n, b as f64 / n)
    }

    /// Largest primitives and bytes drawn in one frame.
    #[must_use]
    pub fn peak_per_frame(&self) -> (u64, u64) {
        let p = self.frames.iter().map(|f| f.primitives).max().unwrap_or(0);
        let b = self.frames.iter().map(|f| f.bytes).max().unwrap_or(0);
        (p, b)
    }

    /// One line for the terminal.
    #[must_use]
    pub fn summary(&self) -> String {
        let (mp, mb) = self.mean_per_frame();
        let (pp, pb) = self.peak_per_frame();
        format!(
            "flight {} ({:?} level under the threshold): {} frames at {} fps, threshold {} px, {}×{}: per frame {:.0} primitives ({pp} peak), \
             {:.0} bytes ({pb} peak) drawn; streamed {} bytes in {} blobs; frames over the threshold: {}",
            self.flight,
            self.rule,
            self.frames.len(),
            self.fps,
            self.threshold_px,
            self.width,
            self.height,
            mp,
            mb,
            self.streamed_bytes,
            self.streamed_blobs,
            self.frames_over_threshold
        )
    }
}

/// Which level the replay's selection draws among those under the threshold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Rule {
    /// The cheapest (the client's rule).
    Cheapest,
    /// The coarsest (the rule before levels were compared by cost), for before/after
    /// comparisons; costs are still counted from the index.
    Coarsest,
}

/// Replays `flight` (read from `flight_path`, named in errors; placed by `bounds` when its
/// frame is normalized) at `fps` over `tree` with everything resident and no fades, as the
/// client's selection would draw it by `rule`.
#[allow(clippy::too_many_arguments)]
pub fn flight_cost(
    flight_path: &std::path::Path,
    tree: &TileTree,
    rule: Rule,
    bounds: &Bounds,
    flight: &Flight,
    (width, height, fov_deg): (u32, u32, f64),
    threshold_px: f64,
    fps: f64,
) -> Result<FlightCost, ClientError> {
    let bad = |source: FlightError| ClientError::Flight { path: flight_path.into(), source };
    if !(fps.is_finite() && fps > 0.0) {
        return Err(bad(FlightError::Fps(fps)));
    }
    let world = flight.to_world(bounds).map_err(bad)?;
    let duration = world.duration();
    let wanted = (duration * fps).floor() + 1.0;
    let n =
        if wanted.is_finite() { (wanted as usize).clamp(1, MAX_FLIGHT_FRAMES) } else { MAX_FLIGHT_FRAMES };
    let ranked;
    let select_tree = match rule {
        Rule::Cheapest => tree,
        Rule::Coarsest => {
            ranked = coarsest_first(tree)?;
            &ranked
        }
    };
    let mut selector =
        Selector::new(SelectParams { threshold_px, fade_seconds: 0.0, ..SelectParams::default() })?;
    let mut seen: HashSet<(TileKey, u8)> = HashSet::new();
    let (mut streamed_bytes, mut over) = (0u64, 0u32);
    let mut draws_per_level: Vec<u64> = Vec::new();
    let mut frames = Vec::with_capacity(n);
    for i in 0..n {
        let t = if n == 1 { world.start() } else { world.start() + duration * i as f64 / (n - 1) as f64 };
        let camera = Camera::new(&world.pose_at(t), width, height, fov_deg);
        // Node ids are the same in both trees (the same nodes inserted in the same order).
        let sel = selector.select(select_tree, &camera, &AllResident, t)?;
        let mut f = FrameCost { t, draws: 0, primitives: 0, bytes: 0, max_error_px: 0.0 };
        let mut frame_over = false;
        for d in sel.draws.iter().filter(|d| !d.retiring) {
            let cost = tree.level_costs(d.node)[usize::from(d.level)];
            f.draws += 1;
            let l = usize::from(d.level);
            if draws_per_level.len() <= l {
                draws_per_level.resize(l + 1, 0);
            }
            draws_per_level[l] += 1;
            f.primitives += u64::from(cost.primitives);
            f.bytes += cost.bytes;
            f.max_error_px = f.max_error_px.max(d.error_px);
            let finest = d.level == 0 && tree.node(d.node).is_leaf();
            frame_over |= d.error_px > threshold_px && !finest;
            if seen.insert((d.key, d.level)) {
                streamed_bytes += cost.bytes;
            }
        }
        over += u32::from(frame_over);
        frames.push(f);
    }
    Ok(FlightCost {
        flight: world.name.clone().unwrap_or_else(|| "unnamed".into()),
        rule,
        fps,
        threshold_px,
        width,
        height,
        frames,
        streamed_bytes,
        streamed_blobs: seen.len() as u64,
        draws_per_level,
        frames_over_threshold: over,
    })
}

/// `tree` with each node's level costs replaced by their rank (every coarser level cheaper than
/// the finer ones), so the selection draws the coarsest level under the threshold — its rule
/// before it compared costs (issue 13), for before/after comparisons (`eval --flight-rule
/// coarsest`). Errors and stored levels are unchanged.
pub fn coarsest_first(tree: &TileTree) -> Result<TileTree, ClientError> {
    let mut out = TileTree::new(*tree.pyramid());
    for (i, n) in tree.nodes().iter().enumerate() {
        let levels: Vec<(u8, f64, LevelCost)> = tree
            .level_errors(i as u32)
            .iter()
            .enumerate()
            .filter(|&(l, _)| n.has_level(l as u8))
            .map(|(l, &e)| {
                let rank = u32::MAX - l as u32;
                (l as u8, e, LevelCost { primitives: rank, bytes: u64::from(rank) })
            })
            .collect();
        out.insert_levels(n.key, n.bounds, &levels)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::client::tree::Synthetic;

    fn orbit() -> Flight {
        Flight::from_json(include_str!("../../data/flight-orbit.json")).unwrap()
    }

    /// Costs add up from the index, streamed bytes count each blob once, and a coarser level
    /// made dearer than level 0 is never drawn once the selection compares costs.
    #[test]
    fn flight_costs_come_from_the_index_and_favour_cheaper_levels() {
        let spec = Synthetic { width: 1025, height: 1025, tile_size: 128, ..Synthetic::with_nodes(1) };
        let tree = TileTree::synthetic(&spec).unwrap();
        let bounds = tree.bounds().unwrap();
        let replay = |t: &TileTree, rule: Rule, threshold: f64| {
            flight_cost(
                std::path::Path::new("orbit.json"),
                t,
                rule,
                &bounds,
                &orbit(),
                (640, 360, 60.0),
                threshold,
                2.0,
            )
            .unwrap()
        };
        let c = replay(&tree, Rule::Cheapest, 1.0);
        assert_eq!(c.frames.len(), 49);
        assert!(c.frames.iter().all(|f| f.draws > 0 && f.primitives > 0));
        let total: u64 = c.frames.iter().map(|f| f.bytes).sum();
        assert!(c.streamed_bytes > 0 && c.streamed_bytes <= total);
        assert_eq!(c.frames_over_threshold, 0);

        // The same tree where every point level costs more than its node's mesh: only meshes.
        let mut dear = TileTree::new(*tree.pyramid());
        for (i, n) in tree.nodes().iter().enumerate() {
            let errs = tree.level_errors(i as u32);
            let levels: Vec<(u8, f64, LevelCost)> = errs
                .iter()
                .enumerate()
                .map(|(l, &e)| {
                    let p = if l == 0 { 100 } else { 1000 };
                    (l as u8, e, LevelCost { primitives: p, bytes: u64::from(p) * 4 })
                })
                .collect();
            dear.insert_levels(n.key, n.bounds, &levels).unwrap();
        }
        // A threshold loose enough that point levels qualify.
        let d = replay(&dear, Rule::Cheapest, 16.0);
        // The rule before costs were compared draws the dearer point levels.
        let before = replay(&dear, Rule::Coarsest, 16.0);
        assert!(before.draws_per_level.iter().skip(1).sum::<u64>() > 0, "{:?}", before.draws_per_level);
        assert_eq!(d.draws_per_level.iter().skip(1).sum::<u64>(), 0, "{:?}", d.draws_per_level);
        let sum = |f: &FlightCost| f.frames.iter().map(|x| x.primitives).sum::<u64>();
        assert!(sum(&before) > 0 && sum(&d) < sum(&before) / 2, "{} vs {}", sum(&d), sum(&before));
        assert!(d.frames.iter().all(|f| f.primitives == u64::from(f.draws) * 100), "{:?}", d.frames[0]);
        assert_eq!(d.frames_over_threshold, 0);
    }

    #[test]
    fn refuses_a_bad_rate() {
        let tree = TileTree::synthetic(&Synthetic::with_nodes(1)).unwrap();
        let b = tree.bounds().unwrap();
        for fps in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(
                flight_cost(
                    std::path::Path::new("orbit.json"),
                    &tree,
                    Rule::Cheapest,
                    &b,
                    &orbit(),
                    (64, 64, 60.0),
                    1.0,
                    fps
                )
                .is_err()
            );
        }
    }
}
