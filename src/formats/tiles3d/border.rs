//! One normal for a vertex that neighbouring terrain GLBs share. A GLB's normals are
//! area-weighted over its own triangles, so the two tiles of a border would light the same vertex
//! with two normals (a visible seam). [`BorderFans`] holds a tile's share of those normals: for
//! each vertex on the edge of its box, the area-weighted sum over the tile's triangles around it,
//! in a frame all tiles share (the tileset's glTF frame, or ECEF on the Earth). The GLB of a tile
//! with its neighbours' fans gives each shared vertex the sum of every tile's share, added in the
//! order of the tiles' keys: the same function of the same blobs on both sides, so both draw one
//! normal (up to their own frames' byte rounding on the Earth).

use std::collections::HashMap;

use glam::DVec3;
use rustc_hash::FxHashMap;

use super::placement::Placement;
use crate::codec::{Blob, Geometry};
use crate::crs::{PlaceError, ecef};
use crate::tiling::TileKey;

/// A terrain mesh tile's share of the normals of the vertices on its box's edge.
#[derive(Debug, Clone)]
pub struct BorderFans {
    key: TileKey,
    /// Per vertex on the box's edge: its index in the mesh and the area-weighted sum of the
    /// normals of the tile's triangles around it (shared frame, each triangle turned to face up).
    verts: Vec<(u32, DVec3)>,
    /// Index into `verts` by the vertex's sample (column, row) of the dataset's grid
    /// ([`Placement::samples`]; the column modulo [`Placement::wrap_cols`]): what two tiles'
    /// vertices of one sample share, whatever each blob's own rounding of its position.
    by_sample: FxHashMap<(i64, i64), u32>,
}

impl BorderFans {
    /// The fans of a mesh blob placed by `place`; `None` for points or a mesh without triangles
    /// or samples. A vertex off the dataset's sample grid (by more than a quarter cell: not a
    /// sample) takes no part. Fails only for a point outside the CRS's or geoid's domain (on the
    /// Earth).
    pub fn of(blob: &Blob, place: &Placement) -> Result<Option<Self>, PlaceError> {
        let Geometry::Mesh(mesh) = &blob.geometry else { return Ok(None) };
        if mesh.triangles.is_empty() {
            return Ok(None);
        }
        let [x0, y0, dx, dy] = place.samples;
        if !(dx.is_finite() && dy.is_finite() && dx != 0.0 && dy != 0.0 && x0.is_finite() && y0.is_finite()) {
            return Ok(None);
        }
        let sample = |p: &[f64; 3]| {
            let (c, r) = ((p[0] - x0) / dx, (p[1] - y0) / dy);
            let near = (c - c.round()).abs() <= 0.25 && (r - r.round()).abs() <= 0.25;
            // Within i64 (a NaN or a huge value is no sample).
            (near && c.abs() < 1e15 && r.abs() < 1e15).then(|| (c.round() as i64, r.round() as i64))
        };
        let samples: Vec<Option<(i64, i64)>> = mesh.positions.iter().map(sample).collect();
        // Around the Earth, column `n` is column 0.
        let key = |(c, r): (i64, i64)| (place.wrap_cols.map_or(c, |n| c.rem_euclid(n)), r);
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for &(c, r) in samples.iter().flatten() {
            (lo, hi) = ((lo.0.min(c), lo.1.min(r)), (hi.0.max(c), hi.1.max(r)));
        }
        // Slot of each vertex on the box's edge (u32::MAX: inside, or no sample).
        let mut slot = vec![u32::MAX; mesh.positions.len()];
        let mut verts = Vec::new();
        let mut by_sample = FxHashMap::default();
        for (i, s) in samples.iter().enumerate() {
            if let &Some((c, r)) = s
                && (c == lo.0 || c == hi.0 || r == lo.1 || r == hi.1)
                && !by_sample.contains_key(&key((c, r)))
            {
                slot[i] = verts.len() as u32;
                by_sample.insert(key((c, r)), verts.len() as u32);
                verts.push((i as u32, DVec3::ZERO));
            }
        }
        if verts.is_empty() {
            return Ok(None);
        }
        // Shared-frame positions of the vertices of triangles that touch the edge, made once.
        let mut shared: FxHashMap<u32, (DVec3, DVec3)> = FxHashMap::default();
        for t in &mesh.triangles {
            if t.iter().all(|&i| slot.get(i as usize).is_none_or(|&s| s == u32::MAX)) {
                continue;
            }
            let mut g = [DVec3::ZERO; 3];
            let mut up = DVec3::ZERO;
            for (k, &i) in t.iter().enumerate() {
                let Some(p) = mesh.positions.get(i as usize) else { continue };
                let e = if let Some(e) = shared.get(&i) {
                    *e
                } else {
                    let e = in_shared_frame(place, *p)?;
                    shared.insert(i, e);
                    e
                };
                g[k] = e.0;
                up += e.1;
            }
            let mut n = (g[1] - g[0]).cross(g[2] - g[0]);
            if n.dot(up) < 0.0 {
                n = -n;
            }
            for &i in t {
                if let Some(&s) = slot.get(i as usize).filter(|&&s| s != u32::MAX) {
                    verts[s as usize].1 += n;
                }
            }
        }
        Ok(Some(Self { key: blob.header.key, verts, by_sample }))
    }

    /// Per vertex this tile shares with at least one of `neighbours` (their fans, any order;
    /// other tiles' keys): its mesh index and its normal in the shared frame, the sum of every
    /// sharing tile's fan in the order of their keys. Vertices no neighbour shares are left out
    /// (they keep the tile's own normal).
    #[must_use]
    pub fn shared_normals(&self, neighbours: &[&BorderFans]) -> Vec<(u32, DVec3)> {
        let mut others: Vec<&BorderFans> = neighbours.iter().copied().filter(|n| n.key != self.key).collect();
        others.sort_by_key(|n| n.key);
        others.dedup_by_key(|n| n.key);
        let mut out = Vec::new();
        let mut parts: Vec<(TileKey, DVec3)> = Vec::with_capacity(4);
        for (sample, &k) in &self.by_sample {
            let (i, own) = self.verts[k as usize];
            parts.clear();
            parts.push((self.key, own));
            for n in &others {
                if let Some(&j) = n.by_sample.get(sample) {
                    parts.push((n.key, n.verts[j as usize].1));
                }
            }
            if parts.len() > 1 {
                parts.sort_by_key(|p| p.0);
                out.push((i, parts.iter().fold(DVec3::ZERO, |s, p| s + p.1)));
            }
        }
        out.sort_unstable_by_key(|v| v.0);
        out
    }

    /// The tile whose fans these are.
    #[must_use]
    pub fn key(&self) -> TileKey {
        self.key
    }

    /// About how much memory the fans hold, bytes.
    #[must_use]
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Self>() + self.verts.len() * (std::mem::size_of::<(u32, DVec3)>() + 40)
    }
}

/// A world point in the frame all tiles share, and the way up there: the tileset's glTF frame
/// (y up) in a local placement, ECEF on the Earth (up: the ellipsoid's normal).
fn in_shared_frame(place: &Placement, p: [f64; 3]) -> Result<(DVec3, DVec3), PlaceError> {
    match &place.earth {
        None => Ok((DVec3::from_array(place.gltf_of(p)), DVec3::Y)),
        Some(frame) => {
            let e = DVec3::from_array(frame.to_ecef(p)?);
            let b2 = 1.0 - ecef::E2;
            Ok((e, DVec3::new(e.x, e.y, e.z / b2)))
        }
    }
}

/// A shared-frame (ECEF) direction in the glTF axes of a node on the Earth whose frame is `enu`
/// (east-north-up at the node's centre, column-major → ECEF). In a local placement the shared
/// frame is the glTF frame already.
#[must_use]
pub fn to_node(enu: &[f64; 16], v: DVec3) -> DVec3 {
    let col = |c: usize| DVec3::new(enu[c * 4], enu[c * 4 + 1], enu[c * 4 + 2]);
    let (e, n, u) = (v.dot(col(0)), v.dot(col(1)), v.dot(col(2)));
    DVec3::new(e, u, -n)
}

/// A tile's fans as the memo hands them out (`None`: the tile has none).
pub type Memoized = std::sync::Arc<Option<BorderFans>>;

/// A bounded memo of tiles' fans for makers of many GLBs (an export, a server), keyed by
/// whatever names a blob there: each blob's fans are made once while they stay in, not once
/// per neighbour. Holds at most `budget` bytes (by [`BorderFans::bytes`]); forgets everything
/// when full (every entry can be made again).
#[derive(Debug)]
pub struct FanCache<K> {
    /// The entries and the bytes they hold.
    map: std::sync::Mutex<(HashMap<K, Memoized>, usize)>,
    budget: usize,
}

impl<K: std::hash::Hash + Eq> FanCache<K> {
    #[must_use]
    pub fn new(budget: usize) -> Self {
        Self { map: std::sync::Mutex::new((HashMap::new(), 0)), budget }
    }

    /// The fans of `key`, made by `make` when not in (outside the lock: two makers of one
    /// key may race, and both get the same fans).
    pub fn get_or_make<E>(
        &self,
        key: K,
        make: impl FnOnce() -> Result<Option<BorderFans>, E>,
    ) -> Result<Memoized, E> {
        if let Some(f) = self.map.lock().unwrap_or_else(std::sync::PoisonError::into_inner).0.get(&key) {
            return Ok(f.clone());
        }
        let f = std::sync::Arc::new(make()?);
        let size = f.as_ref().as_ref().map_or(0, BorderFans::bytes) + 64;
        let mut guard = self.map.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let (map, used) = &mut *guard;
        if *used + size > self.budget {
            map.clear();
            *used = 0;
        }
        if size <= self.budget && map.insert(key, f.clone()).is_none() {
            *used += size;
        }
        Ok(f)
    }

    /// Entries and bytes held now.
    #[must_use]
    pub fn held(&self) -> (usize, usize) {
        let guard = self.map.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        (guard.0.len(), guard.1)
    }
}
