//! OGC 3D Tiles 1.1 from a tileset's own records, so third-party clients (CesiumJS, Cesium for
//! Unreal/Unity, the three.js 3d-tiles-renderer, deck.gl) read every tileset without a re-bake:
//! a decoded blob becomes a glTF 2.0 binary ([`glb()`]) and an index chunk becomes a tileset JSON
//! ([`chunk_tileset`]) whose subtrees below the chunk are external tilesets, so no JSON grows
//! with the dataset. Pure: values in, bytes and JSON out (the server and `export` do the I/O).
//!
//! Placement ([`Placement`]): the tileset frame is east-north-up metres around a local origin
//! (the centre of the data at height 0; a model's bottom centre), and the root tile's
//! `transform` takes it to Earth-centred coordinates at the anchor (longitude, latitude,
//! ellipsoidal height). glTF is y-up, so a glTF position is (east, up, −north). Positions keep
//! the blob's integer grid: each glTF axis stores `q` (or `Q − q` where the axis is reversed)
//! and the node's `translation` and `scale` hold the grid's origin and step, so a position
//! decodes to exactly what the blob decodes to.
//!
//! One file per part: [`placement`] (anchor, axes, the east-north-up frame), [`mod@glb`] (the
//! glTF binary of a blob), [`meshopt`] (its `EXT_meshopt_compression` form, an option), [`draco`] (the
//! `KHR_draco_mesh_compression` form of mesh GLBs, an option), [`tileset`] (tileset JSON, and the GLB of a stored tile as it lists it).

pub mod border;
pub mod draco;
pub mod earth;
pub mod glb;
pub mod meshopt;
pub mod placement;
pub mod tileset;

pub use border::BorderFans;
pub use glb::{ExactNormals, GENERATOR, GLB_TYPE, NormalRole, glb, glb_and_normals, mesh_skirt_depth};
pub use meshopt::MeshoptError;
pub use placement::{
    Anchor, AnchorError, AnchorFrom, AnchorRangeError, Axes, DEFAULT_ANCHOR, MAX_ANCHOR_HEIGHT, Placement,
};
pub use tileset::{
    TilesetInfo, around, chunk_tileset, path_cap, planned_entry, takes_neighbours, tile_fans, tile_glb,
};

/// Errors of the 3D Tiles view: an anchor that cannot be read or lies out of range, a manifest
/// that cannot be read as a tileset's.
#[derive(Debug, thiserror::Error)]
pub enum Tiles3dError {
    #[error(transparent)]
    Anchor(#[from] AnchorError),
    #[error(transparent)]
    AnchorRange(#[from] AnchorRangeError),
    #[error("manifest: {0}")]
    Manifest(#[source] serde_json::Error),
    #[error("manifest: `kind` is {0}, not terrain or model")]
    ManifestKind(serde_json::Value),
    /// The tileset's frame cannot be placed on the Earth (its geoid grid cannot be read).
    #[error("placement: {0}")]
    Frame(#[from] crate::raster::FrameError),
    /// A point of the tileset cannot be placed (outside its CRS's or geoid's domain).
    #[error("placement: {0}")]
    Place(#[from] crate::crs::PlaceError),
    /// The GLB could not be put into `EXT_meshopt_compression` form.
    #[error(transparent)]
    Meshopt(#[from] MeshoptError),
    /// The GLB could not be put into `KHR_draco_mesh_compression` form.
    #[error(transparent)]
    Draco(#[from] draco::DracoError),
}

/// The GLB encoding's revision, carried after the content version in every `?v=` of the 3D
/// Tiles view (`?v=<content version>.g4`): bumped whenever the GLBs of an unchanged tileset
/// change bytes, so caches holding the older `immutable` GLBs and tileset JSON are bypassed.
/// `.g2` (2026-12-07): one node scale for all axes (drawn normals), Draco's geometric normal
/// prediction. `.g3` (2026-12-07): terrain meshes' border vertices take one normal with their
/// neighbours' ([`border`]). `.g4` (2026-12-07): Draco meshes' normals rounded from the exact
/// directions, towards Draco's prediction ([`draco::compress_glb_with`]); on a geographic grid
/// the pole's vertices draw the pole's up, and a grid around the Earth shares its antimeridian
/// vertices' normals.
pub const GLB_REVISION: &str = ".g4";

/// How the 3D Tiles GLBs are compressed: `none` (plain buffers, the default), `meshopt`
/// (`EXT_meshopt_compression`, which the reader must support: CesiumJS does natively, three.js
/// with `GLTFLoader.setMeshoptDecoder`) or `draco` (`KHR_draco_mesh_compression` for mesh GLBs,
/// [`draco`]: CesiumJS natively, three.js with `DRACOLoader`; the extension covers
/// triangles only, so point levels' GLBs take `EXT_meshopt_compression` there).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GlbCompression {
    #[default]
    None,
    Meshopt,
    Draco,
}

impl GlbCompression {
    /// Every option, in the order documented.
    pub const ALL: [Self; 3] = [Self::None, Self::Meshopt, Self::Draco];

    /// The option's name (`none`, `meshopt`, `draco`), as `--glb-compression` and `?glb=` take it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Meshopt => "meshopt",
            Self::Draco => "draco",
        }
    }

    /// The option named `s`, if it is one.
    #[must_use]
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == s)
    }

    /// A GLB of [`super::glb()`] in this compression.
    ///
    /// # Errors
    /// As [`meshopt::compress_glb`] and [`draco::compress_glb`].
    pub fn apply(self, glb: Vec<u8>) -> Result<Vec<u8>, Tiles3dError> {
        self.apply_with(glb, None)
    }

    /// [`Self::apply`] to a GLB of [`glb_and_normals`], whose `normals` (its mesh's, when
    /// given) Draco rounds from ([`draco::compress_glb_with`]).
    ///
    /// # Errors
    /// As [`Self::apply`].
    pub fn apply_with(self, glb: Vec<u8>, normals: Option<&ExactNormals>) -> Result<Vec<u8>, Tiles3dError> {
        Ok(match self {
            Self::None => glb,
            Self::Draco if draco::all_triangles(&glb) => draco::compress_glb_with(&glb, normals)?,
            Self::Meshopt | Self::Draco => meshopt::compress_glb(&glb)?,
        })
    }
}

#[cfg(test)]
mod tests;
