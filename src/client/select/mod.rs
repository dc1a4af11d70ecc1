//! View-dependent tile and level selection (the second paper's region-tree control on the tile
//! quadtree), level fades (the first paper) and crack-hiding skirts. Pure: the caller passes the
//! tree, the camera, what is resident and the time.
//!
//! Per frame, [`Selector::select`]:
//! 1. starts from last frame's active set (the cut through the tree; the root on the first
//!    frame) — temporal coherence: only cut nodes, their children on a split and their parents
//!    on a merge are evaluated;
//! 2. culls each node by its subtree box against the view frustum and computes, per level, the
//!    screen-space error `e_scr = e_obj · k / |R − E|`, `k = w / (2·tan(φ/2))`; the node's level
//!    is the coarsest one with `e_scr ≤ threshold`;
//! 3. down-switch: a visible node whose level 0 is still too coarse is replaced by its children
//!    (when the index chunk holding them has arrived; otherwise it stays and the chunk is asked
//!    for); up-switch: when every child of a parent is in the cut and the parent is culled or has
//!    a level under the threshold, the children merge into it. The split and merge tests are
//!    complements, so the cut converges to the same one whatever the history;
//! 4. decides what is drawn from what is resident, never leaving a hole that resident data could
//!    fill: a cut node draws its resident level closest to the wanted one (finer preferred); if it
//!    has none, the nodes below it that were drawn last frame keep standing in for it; if those do
//!    not cover it, its nearest resident ancestor is drawn instead of the whole subtree;
//! 5. fades: a tile that replaces others fades in over `fade_seconds` while the tiles it replaces
//!    keep being drawn as `retiring` with the complementary alpha (renderers use complementary
//!    dither masks, so every pixel shows exactly one of them);
//! 6. lists the wanted (tile, level) pairs that are not resident with a priority (the screen-space
//!    error of what stands in for them now; infinite for a hole) and the index chunks needed.

use std::collections::HashMap;

use crate::client::ClientError;
use glam::DVec3;

use crate::client::camera::MIN_DISTANCE;
pub use crate::client::camera::{Camera, View};
use crate::client::tree::{NO_NODE, NodeId, TileTree};
use crate::geom::Bounds;
/// Skirts live with the geometry; re-exported here, where selection decides their depth.
pub use crate::geom::{Skirted, add_skirts, skirt_depth};
use crate::store;
use crate::tiling::TileKey;

/// Level value of a node whose level 0 is still over the threshold.
const TOO_COARSE: u8 = u8::MAX;

/// Screen-space error threshold in pixels (`--threshold`). One pixel, the second paper's: at
/// 2 px a point level may be drawn while its error is a twentieth of a distant model's size,
/// and coverage precision fell to 0.93–0.96 at the evaluation's farthest views; at 1 px every
/// development model and terrain kept precision ≥ 0.97 at every distance (docs/evaluation.md).
pub const DEFAULT_THRESHOLD_PX: f64 = 1.0;
/// Horizontal field of view in degrees (`--fov`).
pub const DEFAULT_FOV_DEG: f64 = 60.0;
/// Duration of a level cross-fade in seconds.
pub const DEFAULT_FADE_SECONDS: f64 = 0.25;

/// What is resident: for a tile, the bit mask of its levels that are decoded and ready to draw
/// (bit `l` = level `l`).
pub trait Residency {
    fn levels(&self, key: TileKey) -> u32;
}

/// Everything is resident (benchmarks, and the full-detail reference).
#[derive(Debug, Clone, Copy, Default)]
pub struct AllResident;

impl Residency for AllResident {
    fn levels(&self, _key: TileKey) -> u32 {
        u32::MAX
    }
}

impl<S: std::hash::BuildHasher> Residency for HashMap<TileKey, u32, S> {
    fn levels(&self, key: TileKey) -> u32 {
        self.get(&key).copied().unwrap_or(0)
    }
}

/// A residency query from a closure.
pub struct FnResidency<F>(pub F);

impl<F: Fn(TileKey) -> u32> Residency for FnResidency<F> {
    fn levels(&self, key: TileKey) -> u32 {
        (self.0)(key)
    }
}

/// Which distance `e_scr` divides by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DistanceRule {
    /// `|R − E|` with R the centre of the node's bounding sphere (the paper's rule).
    #[default]
    Centre,
    /// Distance from the eye to the nearest point of the node's subtree box: conservative for
    /// large nodes seen from close by (never under-estimates the error anywhere on the tile),
    /// and never larger for a child than for its parent, so with errors that shrink with depth
    /// the cut does not depend on the path the camera took.
    Nearest,
}

/// Selection settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelectParams {
    pub threshold_px: f64,
    /// Cross-fade duration in seconds; 0 switches levels at once.
    pub fade_seconds: f64,
    pub distance: DistanceRule,
}

impl Default for SelectParams {
    fn default() -> Self {
        Self {
            threshold_px: DEFAULT_THRESHOLD_PX,
            fade_seconds: DEFAULT_FADE_SECONDS,
            distance: DistanceRule::Centre,
        }
    }
}

/// One tile level to draw this frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrawItem {
    pub node: NodeId,
    pub key: TileKey,
    pub level: u8,
    /// Opacity in 0..=1 (fade in for new tiles, fade out for retiring ones).
    pub alpha: f32,
    /// A tile that was replaced and is fading out; draw it with dither mask `≥ 1 − alpha` so it
    /// and its replacement (mask `< alpha`) cover every pixel exactly once between them.
    pub retiring: bool,
    /// Screen-space error of this level at this node, in pixels.
    pub error_px: f64,
    /// The level's geometric error in world units (skirt depth: see [`skirt_depth`]).
    pub error_world: f64,
}

/// A (tile, level) the selection wants and is not resident.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Want {
    pub node: NodeId,
    pub key: TileKey,
    pub level: u8,
    /// Screen-space error in pixels of what is drawn in its place now: infinite for a hole,
    /// 0 when finer tiles stand in for it. Fetch larger first.
    pub priority_px: f64,
}

/// Counters of one selection.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SelectStats {
    /// Nodes whose visibility and error were evaluated (the paper's control cost measure).
    pub visited: u32,
    /// Nodes in the active set (the cut), visible or not.
    pub active: u32,
    /// Cut nodes inside the frustum.
    pub visible: u32,
    /// Draw items per level (retiring ones excluded).
    pub drawn_per_level: Vec<u32>,
    /// Retiring (fading-out) draw items.
    pub retiring: u32,
    /// Visible cut nodes that nothing resident covers.
    pub holes: u32,
    /// Largest screen-space error among the drawn (non-retiring) items.
    pub max_error_px: f64,
    /// True when every drawn (non-retiring) item is under the threshold.
    pub under_threshold: bool,
}

/// The result of one frame's selection.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Selection {
    pub draws: Vec<DrawItem>,
    pub wants: Vec<Want>,
    /// Index chunks (by root key) needed to split nodes further.
    pub missing_chunks: Vec<TileKey>,
    pub stats: SelectStats,
}

#[derive(Debug, Clone, Copy, Default)]
struct Eval {
    visible: bool,
    level: u8,
}

#[derive(Debug, Clone, Copy, Default)]
struct Slot {
    frame: u32,
    level: u8,
    /// Time the (node, level) started being drawn (its fade-in start); NaN while undecided.
    start: f64,
}

#[derive(Debug, Clone, Copy)]
struct Retiring {
    node: NodeId,
    level: u8,
    start: f64,
}

/// Per-node scratch arrays, stamped with the frame number instead of cleared.
#[derive(Debug, Default, Clone)]
struct Scratch {
    eval_frame: Vec<u32>,
    eval: Vec<Eval>,
    cut: Vec<u32>,
    above: Vec<u32>,
    checked: Vec<u32>,
    /// Node or a descendant drawn (non-retiring) in the stamped frame.
    mark: Vec<u32>,
    slot: Vec<Slot>,
    ret_self: Vec<u32>,
    ret_mark: Vec<u32>,
}

impl Scratch {
    fn grow(&mut self, n: usize) {
        if self.eval.len() < n {
            self.eval_frame.resize(n, 0);
            self.eval.resize(n, Eval::default());
            self.cut.resize(n, 0);
            self.above.resize(n, 0);
            self.checked.resize(n, 0);
            self.mark.resize(n, 0);
            self.slot.resize(n, Slot::default());
            self.ret_self.resize(n, 0);
            self.ret_mark.resize(n, 0);
        }
    }
}

/// The selection state carried from frame to frame.
#[derive(Debug, Clone)]
pub struct Selector {
    params: SelectParams,
    frame: u32,
    cut: Vec<NodeId>,
    next_cut: Vec<NodeId>,
    work: Vec<NodeId>,
    merged: Vec<NodeId>,
    s: Scratch,
    prev_draws: Vec<(NodeId, u8)>,
    retiring: Vec<Retiring>,
    out: Selection,
}

struct Ctx<'a, R: Residency + ?Sized> {
    tree: &'a TileTree,
    view: &'a View,
    res: &'a R,
}

fn level_mask(count: usize) -> u32 {
    if count >= 32 { u32::MAX } else { (1u32 << count) - 1 }
}

impl Selector {
    pub fn new(params: SelectParams) -> Result<Self, ClientError> {
        if !(params.threshold_px.is_finite() && params.threshold_px > 0.0) {
            return Err(ClientError::Camera(format!(
                "threshold {} px must be positive",
                params.threshold_px
            )));
        }
        if !(params.fade_seconds.is_finite() && params.fade_seconds >= 0.0) {
            return Err(ClientError::Camera(format!(
                "fade time {} s must be 0 or more",
                params.fade_seconds
            )));
        }
        Ok(Self::fresh(params))
    }

    fn fresh(params: SelectParams) -> Self {
        Self {
            params,
            frame: 1,
            cut: Vec::new(),
            next_cut: Vec::new(),
            work: Vec::new(),
            merged: Vec::new(),
            s: Scratch::default(),
            prev_draws: Vec::new(),
            retiring: Vec::new(),
            out: Selection::default(),
        }
    }

    #[must_use]
    pub fn params(&self) -> &SelectParams {
        &self.params
    }

    /// The active set (the cut) after the last selection.
    #[must_use]
    pub fn active(&self) -> &[NodeId] {
        &self.cut
    }

    /// Forgets the active set, draws and fades (for a new tree or a camera jump).
    pub fn reset(&mut self) {
        *self = Self::fresh(self.params);
    }

    /// Selects what to draw and what to fetch for one frame at time `now` (seconds).
    pub fn select<R: Residency + ?Sized>(
        &mut self,
        tree: &TileTree,
        camera: &Camera,
        res: &R,
        now: f64,
    ) -> Result<&Selection, ClientError> {
        let view = camera.view()?;
        self.frame = self.frame.wrapping_add(1).max(2);
        self.s.grow(tree.len());
        let mut out = std::mem::take(&mut self.out);
        out.draws.clear();
        out.wants.clear();
        out.missing_chunks.clear();
        out.stats = SelectStats::default();
        let Some(root) = tree.root() else {
            self.out = out;
            return Ok(&self.out);
        };
        if self.cut.is_empty() || self.cut.iter().any(|&n| n as usize >= tree.len()) {
            self.cut.clear();
            self.cut.push(root);
        }
        let ctx = Ctx { tree, view: &view, res };
        self.refine(&ctx, &mut out);
        self.merge(&ctx, &mut out);
        self.collect_cut();
        self.mark_above(tree);
        self.cover_root(&ctx, root, &mut out);
        self.finish_draws(&ctx, now, &mut out);
        self.wants(&ctx, &mut out);
        out.missing_chunks.sort();
        out.missing_chunks.dedup();
        out.stats.active = self.cut.len() as u32;
        self.out = out;
        Ok(&self.out)
    }

    fn eval<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, n: NodeId, stats: &mut SelectStats) -> Eval {
        let i = n as usize;
        if self.s.eval_frame[i] == self.frame {
            return self.s.eval[i];
        }
        stats.visited += 1;
        let node = ctx.tree.node(n);
        let visible = ctx.view.intersects(&node.cull);
        let dist = self.distance(ctx.view, node.center, &node.cull);
        let mut level = TOO_COARSE;
        if visible {
            // e·k/d ≤ t  ⇔  e ≤ t·d/k: one multiply per node, one compare per level.
            let allowed = self.params.threshold_px * dist.max(MIN_DISTANCE) / ctx.view.k;
            // Among the levels under the threshold the cheapest (a tie goes to the coarser);
            // a level the node does not store has an infinite error.
            let errs = ctx.tree.level_errors(n);
            let costs = ctx.tree.level_costs(n);
            if let Some(l) = (0..errs.len()).rev().filter(|&l| errs[l] <= allowed).min_by_key(|&l| costs[l]) {
                level = l as u8;
            }
        }
        let e = Eval { visible, level };
        self.s.eval_frame[i] = self.frame;
        self.s.eval[i] = e;
        e
    }

    fn distance(&self, view: &View, center: DVec3, b: &Bounds) -> f64 {
        match self.params.distance {
            DistanceRule::Centre => (center - view.eye).length(),
            DistanceRule::Nearest => {
                let e = view.eye;
                (b.min - e).max(e - b.max).max(DVec3::ZERO).length()
            }
        }
    }

    /// Down-switches: walk last frame's cut, replacing visible too-coarse nodes by their children.
    fn refine<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, out: &mut Selection) {
        self.work.clear();
        self.work.extend_from_slice(&self.cut);
        self.next_cut.clear();
        while let Some(n) = self.work.pop() {
            let e = self.eval(ctx, n, &mut out.stats);
            let node = ctx.tree.node(n);
            if e.visible && e.level == TOO_COARSE && !node.is_leaf() {
                if node.children_loaded() {
                    self.work.extend(node.loaded_children());
                    continue;
                }
                let pk = ctx.tree.pyramid();
                if let Some(c) = pk.children(node.key).first() {
                    out.missing_chunks.push(store::chunk_root(*c));
                }
            }
            self.s.cut[n as usize] = self.frame;
            self.next_cut.push(n);
        }
    }

    /// Up-switches: merge complete sibling groups whose parent is culled or under the threshold.
    fn merge<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, out: &mut Selection) {
        self.merged.clear();
        let mut i = 0;
        while i < self.next_cut.len() + self.merged.len() {
            let n =
                if i < self.next_cut.len() { self.next_cut[i] } else { self.merged[i - self.next_cut.len()] };
            i += 1;
            let p = ctx.tree.node(n).parent;
            if p == NO_NODE
                || self.s.checked[p as usize] == self.frame
                || self.s.cut[n as usize] != self.frame
            {
                continue;
            }
            self.s.checked[p as usize] = self.frame;
            let parent = ctx.tree.node(p);
            if !parent.children_loaded()
                || !parent.loaded_children().all(|c| self.s.cut[c as usize] == self.frame)
            {
                continue;
            }
            let e = self.eval(ctx, p, &mut out.stats);
            if !e.visible || e.level != TOO_COARSE {
                for c in parent.loaded_children() {
                    self.s.cut[c as usize] = 0;
                }
                self.s.cut[p as usize] = self.frame;
                self.merged.push(p);
                // The grandparent may have been checked before this merge completed its group.
                let pp = parent.parent;
                if pp != NO_NODE {
                    self.s.checked[pp as usize] = 0;
                }
            }
        }
    }

    fn collect_cut(&mut self) {
        let f = self.frame;
        self.cut.clear();
        for &n in self.next_cut.iter().chain(self.merged.iter()) {
            if self.s.cut[n as usize] == f {
                self.cut.push(n);
            }
        }
        // A merged parent can be listed once per merge attempt; keep one.
        self.cut.sort_unstable();
        self.cut.dedup();
    }

    fn mark_above(&mut self, tree: &TileTree) {
        let f = self.frame;
        for &n in &self.cut {
            let mut a = tree.node(n).parent;
            while a != NO_NODE && self.s.above[a as usize] != f {
                self.s.above[a as usize] = f;
                a = tree.node(a).parent;
            }
        }
    }

    fn cover_root<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, root: NodeId, out: &mut Selection) {
        if self.s.cut[root as usize] == self.frame || self.s.above[root as usize] == self.frame {
            self.cover(ctx, root, out);
        }
    }

    fn push_draw<R: Residency + ?Sized>(&self, ctx: &Ctx<'_, R>, n: NodeId, level: u8, out: &mut Selection) {
        let node = ctx.tree.node(n);
        let dist = self.distance(ctx.view, node.center, &node.cull);
        let e = ctx.tree.level_errors(n)[usize::from(level)];
        out.draws.push(DrawItem {
            node: n,
            key: node.key,
            level,
            alpha: 1.0,
            retiring: false,
            error_px: ctx.view.screen_error(e, dist),
            error_world: e,
        });
    }

    fn resident<R: Residency + ?Sized>(ctx: &Ctx<'_, R>, n: NodeId) -> u32 {
        let node = ctx.tree.node(n);
        ctx.res.levels(node.key) & level_mask(node.level_count()) & node.level_mask()
    }

    /// Draws for a cut node or a node above the cut; true when its whole visible area is covered.
    fn cover<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, n: NodeId, out: &mut Selection) -> bool {
        let i = n as usize;
        if self.s.cut[i] == self.frame {
            let e = self.s.eval[i];
            if !e.visible {
                return true;
            }
            let mask = Self::resident(ctx, n);
            if mask != 0 {
                let want = if e.level == TOO_COARSE { 0 } else { u32::from(e.level) };
                // Coarsest resident level at or finer than the wanted one, else the finest coarser.
                let at_or_finer = mask & ((2u32 << want).wrapping_sub(1));
                let level = if at_or_finer != 0 { at_or_finer.ilog2() } else { mask.trailing_zeros() };
                self.push_draw(ctx, n, level as u8, out);
                return true;
            }
            return self.cover_below_children(ctx, n, out);
        }
        // Above the cut: every loaded child is in the cut or above it.
        let start = out.draws.len();
        let mut all = true;
        for c in ctx.tree.node(n).loaded_children() {
            all &= self.cover(ctx, c, out);
        }
        if all {
            return true;
        }
        let mask = Self::resident(ctx, n);
        if mask != 0 {
            // Keep drawing the node itself until all its children have arrived.
            out.draws.truncate(start);
            self.push_draw(ctx, n, mask.trailing_zeros() as u8, out);
            return true;
        }
        false
    }

    /// Stand-ins below a non-resident node: only subtrees drawn last frame are searched, so the
    /// cost stays proportional to what was drawn.
    fn cover_below_children<R: Residency + ?Sized>(
        &mut self,
        ctx: &Ctx<'_, R>,
        n: NodeId,
        out: &mut Selection,
    ) -> bool {
        let node = ctx.tree.node(n);
        if self.s.mark[n as usize] != self.frame - 1 || node.is_leaf() || !node.children_loaded() {
            return false;
        }
        let mut all = true;
        for c in node.loaded_children() {
            all &= self.cover_below(ctx, c, out);
        }
        all
    }

    fn cover_below<R: Residency + ?Sized>(
        &mut self,
        ctx: &Ctx<'_, R>,
        n: NodeId,
        out: &mut Selection,
    ) -> bool {
        out.stats.visited += 1;
        if !ctx.view.intersects(&ctx.tree.node(n).cull) {
            return true;
        }
        let mask = Self::resident(ctx, n);
        if mask != 0 {
            self.push_draw(ctx, n, mask.ilog2() as u8, out);
            return true;
        }
        self.cover_below_children(ctx, n, out)
    }

    /// Marks, fades and retiring items.
    fn finish_draws<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, now: f64, out: &mut Selection) {
        let f = self.frame;
        let fade = self.params.fade_seconds;
        // Carry fade starts of items drawn last frame at the same level; mark drawn subtrees.
        for d in &out.draws {
            let i = d.node as usize;
            let old = self.s.slot[i];
            let start = if old.frame == f - 1 && old.level == d.level { old.start } else { f64::NAN };
            self.s.slot[i] = Slot { frame: f, level: d.level, start };
            let mut a = d.node;
            while a != NO_NODE && self.s.mark[a as usize] != f {
                self.s.mark[a as usize] = f;
                a = ctx.tree.node(a).parent;
            }
        }
        // Retiring: drawn last frame, not now, still visible and resident; plus older ones still
        // fading out.
        let mut retiring = std::mem::take(&mut self.retiring);
        if fade > 0.0 {
            for &(n, level) in &self.prev_draws {
                let slot = self.s.slot[n as usize];
                if slot.frame != f || slot.level != level {
                    retiring.push(Retiring { node: n, level, start: now });
                }
            }
        }
        retiring.retain(|r| {
            let slot = self.s.slot[r.node as usize];
            let node = ctx.tree.node(r.node);
            (slot.frame != f || slot.level != r.level)
                && now - r.start < fade
                && ctx.view.intersects(&node.cull)
                && ctx.res.levels(node.key) & (1 << r.level) != 0
        });
        retiring.sort_by_key(|r| (r.node, r.level));
        retiring.dedup_by_key(|r| (r.node, r.level));
        for r in &retiring {
            self.s.ret_self[r.node as usize] = f;
            let mut a = r.node;
            while a != NO_NODE && self.s.ret_mark[a as usize] != f {
                self.s.ret_mark[a as usize] = f;
                a = ctx.tree.node(a).parent;
            }
        }
        // New items fade in only where they replace a retiring item (same node, an ancestor or a
        // descendant); elsewhere (first frame, area coming into view) they appear at once.
        let mut stats = std::mem::take(&mut out.stats);
        stats.under_threshold = true;
        for d in &mut out.draws {
            let i = d.node as usize;
            if self.s.slot[i].start.is_nan() {
                let replaces = self.s.ret_mark[i] == f || {
                    let mut a = ctx.tree.node(d.node).parent;
                    while a != NO_NODE && self.s.ret_self[a as usize] != f {
                        a = ctx.tree.node(a).parent;
                    }
                    a != NO_NODE
                };
                self.s.slot[i].start = if replaces { now } else { now - fade };
            }
            d.alpha =
                if fade > 0.0 { ((now - self.s.slot[i].start) / fade).clamp(0.0, 1.0) as f32 } else { 1.0 };
            let l = usize::from(d.level);
            if stats.drawn_per_level.len() <= l {
                stats.drawn_per_level.resize(l + 1, 0);
            }
            stats.drawn_per_level[l] += 1;
            stats.max_error_px = stats.max_error_px.max(d.error_px);
            stats.under_threshold &= d.error_px <= self.params.threshold_px;
        }
        self.prev_draws.clear();
        self.prev_draws.extend(out.draws.iter().map(|d| (d.node, d.level)));
        for r in &retiring {
            let node = ctx.tree.node(r.node);
            let e = ctx.tree.level_errors(r.node)[usize::from(r.level)];
            let dist = self.distance(ctx.view, node.center, &node.cull);
            out.draws.push(DrawItem {
                node: r.node,
                key: node.key,
                level: r.level,
                alpha: (1.0 - (now - r.start) / fade).clamp(0.0, 1.0) as f32,
                retiring: true,
                error_px: ctx.view.screen_error(e, dist),
                error_world: e,
            });
        }
        stats.retiring = retiring.len() as u32;
        out.stats = stats;
        self.retiring = retiring;
    }

    fn wants<R: Residency + ?Sized>(&mut self, ctx: &Ctx<'_, R>, out: &mut Selection) {
        let f = self.frame;
        for &n in &self.cut {
            let e = self.s.eval[n as usize];
            if !e.visible {
                continue;
            }
            out.stats.visible += 1;
            let level = if e.level == TOO_COARSE { 0 } else { e.level };
            let node = ctx.tree.node(n);
            let mask = ctx.res.levels(node.key);
            if mask & (1 << level) != 0 {
                continue;
            }
            // What stands in for it now: itself at another level, an ancestor, or descendants.
            let slot = self.s.slot[n as usize];
            let priority_px = if slot.frame == f {
                self.drawn_error_px(ctx, n, slot.level)
            } else {
                let mut a = node.parent;
                while a != NO_NODE && self.s.slot[a as usize].frame != f {
                    a = ctx.tree.node(a).parent;
                }
                if a != NO_NODE {
                    self.drawn_error_px(ctx, a, self.s.slot[a as usize].level)
                } else if self.s.mark[n as usize] == f {
                    0.0
                } else {
                    out.stats.holes += 1;
                    f64::INFINITY
                }
            };
            out.wants.push(Want { node: n, key: node.key, level, priority_px });
        }
    }

    fn drawn_error_px<R: Residency + ?Sized>(&self, ctx: &Ctx<'_, R>, n: NodeId, level: u8) -> f64 {
        let node = ctx.tree.node(n);
        let dist = self.distance(ctx.view, node.center, &node.cull);
        ctx.view.screen_error(ctx.tree.level_errors(n)[usize::from(level)], dist)
    }
}

#[cfg(test)]
mod tests;
