//! A streaming session's renderer: what the session's selection draws, uploaded from its cache
//! to a [`Renderer`] (feature `gpu`).

use std::collections::HashMap;

use crate::client::render::{Renderer, footprint_half, point_spacing};
use crate::client::select::skirt_depth;
use crate::client::stream::session::Session;
use crate::codec::Geometry;
use crate::geom::Bounds;
use crate::gpu::{GpuContext, GpuError};
use crate::tiling::TileKey;

/// Draws a live [`Session`]'s frames: each (tile, level) the selection draws is uploaded from
/// the session's cache the first time it is drawn and kept on the GPU until the cache drops it
/// (so GPU memory is bounded by the cache budget).
///
/// Mesh skirts: a mesh's neighbour is one of the tiles drawn with it, so the crack to hide is at
/// most `skirt_depth(own, largest drawn error)`. A mesh is uploaded with twice the depth the
/// frame needs and re-made only when a later frame needs more than it has: depths grow
/// geometrically, so re-uploads are rare, and a deeper skirt than needed is hidden below the
/// neighbouring surface.
pub struct SessionView {
    renderer: Renderer,
    skirts: HashMap<(TileKey, u8), f64>,
    outer: Bounds,
    far: f64,
    uploads: u64,
}

impl SessionView {
    /// A renderer of the session's viewport on `ctx`'s device, origin at the tileset's lower
    /// corner.
    pub fn new(ctx: GpuContext, session: &Session, width: u32, height: u32) -> Result<Self, GpuError> {
        let b = session.manifest().bounds;
        let size = b.size();
        let renderer = Renderer::new(ctx.device, ctx.queue, width, height, b.min)?;
        // Far plane: the flight may leave the tileset; several extents cover any sensible pose.
        let far = 8.0 * (size[0].abs() + size[1].abs() + size[2].abs()).max(1.0);
        Ok(Self { renderer, skirts: HashMap::new(), outer: b, far, uploads: 0 })
    }

    #[must_use]
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// Uploads (re-made tiles included) so far.
    #[must_use]
    pub fn uploads(&self) -> u64 {
        self.uploads
    }

    /// Draws the session's last frame; reads it back when `read_back`. Nothing is drawn before
    /// the session's first frame.
    pub fn draw(&mut self, session: &Session, read_back: bool) -> Result<Option<image::RgbaImage>, GpuError> {
        let Some(camera) = session.camera().copied() else { return Ok(None) };
        let cache = session.cache();
        // Free what the cache no longer holds.
        let gone: Vec<(TileKey, u8)> =
            self.skirts.keys().copied().filter(|&(k, l)| !cache.contains(k, l)).collect();
        for (k, l) in gone {
            self.skirts.remove(&(k, l));
            self.renderer.evict(k, l);
        }
        let draws = session.draws();
        let max_e = draws.iter().map(|d| d.error_world).fold(0.0, f64::max);
        for d in draws {
            let needed = skirt_depth(d.error_world, max_e);
            let have = self.skirts.get(&(d.key, d.level)).copied();
            if have.is_some_and(|h| h >= needed) {
                continue;
            }
            let Some(blob) = cache.peek(d.key, d.level) else { continue };
            let depth = 2.0 * needed;
            if have.is_some() {
                self.renderer.evict(d.key, d.level);
            }
            let spacing = point_spacing(session.manifest(), session.tree(), d.key, d.level);
            let half = footprint_half(session.manifest(), d.level);
            self.renderer.upload(blob, depth, Some(&self.outer), spacing, half);
            // Point levels have no skirts: any depth will do for them.
            let kept = if matches!(blob.geometry, Geometry::Mesh(_)) { depth } else { f64::INFINITY };
            self.skirts.insert((d.key, d.level), kept);
            self.uploads += 1;
        }
        if read_back {
            self.renderer.render(&camera, draws, self.far).map(Some)
        } else {
            self.renderer.draw(&camera, draws, self.far).map(|()| None)
        }
    }
}
