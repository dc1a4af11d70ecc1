//! Cesium quantized-mesh-1.0 terrain: the global geodetic tiling ([`grid`]), the binary format
//! ([`codec`]), one tile from its sample grid ([`build`]) and the `layer.json` that describes a
//! tileset's terrain ([`layer`]). Pure: heights in, bytes and JSON out; reading the source and
//! writing or serving tiles is `bake::qmesh`'s and the server's.
//!
//! Why our own encoder rather than the `quantized-mesh` crate: the tiles' guarantees live in
//! how the mesh is made, not in the byte layout (heights on a shared edge lattice, vertices in
//! first-use order, every extension made once and filtered per request without a re-encode),
//! and the codec is 300 lines with a bounds-checked decoder the server and tests share. The
//! independent decoders are in `tests/interop/`: `@here/quantized-mesh-decoder`, CesiumJS and
//! 3DTilesRendererJS read every tile of the shared DEMs.

pub mod build;
pub mod codec;
pub mod grid;
pub mod layer;
pub mod tiles3d;

pub use build::{BuildError, BuiltTile, SIDE, TileSamples, build_tile};
pub use codec::{Extensions, QmError, QmTile, decode, encode, filter_extensions};
pub use grid::{Rect, TileId, TileIdError};

/// The media type of quantized-mesh tiles.
pub const QM_TYPE: &str = "application/vnd.quantized-mesh";

impl TileSamples {
    /// The samples of tile `id` from a height function of WGS 84 longitude (wrapped to
    /// −180…180, the antimeridian always −180) and latitude: `None` where there is no data, which takes `fill`'s height and
    /// is flagged.
    pub fn from_fn(
        id: TileId,
        mut height: impl FnMut(f64, f64) -> Option<f64>,
        mut fill: impl FnMut(f64, f64) -> f64,
    ) -> Self {
        let n = i64::from(grid::SAMPLES);
        let mut heights = Vec::with_capacity(SIDE * SIDE);
        let mut nodata = Vec::with_capacity((n * n) as usize);
        for j in -1..=n {
            for i in -1..=n {
                let (lon, lat) = id.sample(i, j);
                let lon = grid::canonical_lon(lon);
                let h = height(lon, lat);
                let inner = (0..n).contains(&i) && (0..n).contains(&j);
                if inner {
                    nodata.push(h.is_none());
                }
                heights.push(h.unwrap_or_else(|| fill(lon, lat)));
            }
        }
        Self { id, heights, nodata, relief: None }
    }
}
