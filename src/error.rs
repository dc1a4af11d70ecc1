//! The library's error type: one enum per stage, gathered here so callers can match on the
//! stage that failed while `?` converts between them.
//!
//! Each stage returns its own enum (`RasterError`, `BakeError`, `ClientError`, …): a function
//! says exactly which failures it can have, and the HTTP handlers map variants to status codes.
//! [`Error`] is for callers that drive several stages in one function and want one type for
//! any of them — an application embedding the pipeline (load a raster, bake it, serve it) writes
//! `fn run() -> terrastream::Result<()>` and uses `?` on every stage's result. Its text is the
//! stage error's text, unchanged. The `terrastream` binary itself reports errors through
//! `anyhow` (which takes any of these), so it does not name this type.

use crate::{
    bake::BakeError, bake::export::ExportError, bake::model_tileset::ModelBakeError, codec::CodecError,
    formats::tiles3d::Tiles3dError, lod::BakerError, model::MeshError, raster::RasterError,
    store::StoreError, store::archive::ArchiveError, tiling::TilingError, tin::TinError,
};

/// A failure of any stage of the pipeline (see the module doc); the variant names the stage.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error(transparent)]
    Tiling(#[from] TilingError),
    #[error(transparent)]
    Tin(#[from] TinError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    /// Opening the point baker (`--gpu`).
    #[error(transparent)]
    Baker(#[from] BakerError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Archive(#[from] ArchiveError),
    #[error(transparent)]
    Bake(#[from] BakeError),
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    ModelBake(#[from] ModelBakeError),
    #[error(transparent)]
    Tiles3d(#[from] Tiles3dError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[cfg(feature = "server")]
    #[error(transparent)]
    Server(#[from] crate::server::ServerError),
    #[cfg(feature = "client")]
    #[error(transparent)]
    Client(#[from] crate::client::ClientError),
    #[cfg(feature = "client")]
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    /// Converts `e` into [`Error`] as `?` does and checks the text is the stage error's.
    fn kept<E: std::error::Error + Into<Error>>(e: E) -> Error {
        let text = e.to_string();
        let err: Error = e.into();
        assert_eq!(err.to_string(), text);
        err
    }

    #[test]
    fn every_stage_converts_and_keeps_its_message() {
        let p = || PathBuf::from("/x/y");
        assert!(matches!(kept(RasterError::ZeroSize { path: p(), width: 0, height: 3 }), Error::Raster(_)));
        assert!(matches!(kept(TilingError::BadTileSize(0)), Error::Tiling(_)));
        assert!(matches!(kept(TinError::BadMaxError(-1.0)), Error::Tin(_)));
        assert!(matches!(kept(CodecError::BadMagic(*b"XXXX")), Error::Codec(_)));
        assert!(matches!(kept(BakerError::NoGpuSupport), Error::Baker(_)));
        assert!(matches!(kept(StoreError::NotATileset { path: p() }), Error::Store(_)));
        assert!(matches!(kept(ArchiveError::Format("short".into())), Error::Archive(_)));
        assert!(matches!(kept(BakeError::Levels(99)), Error::Bake(_)));
        assert!(matches!(
            kept(MeshError::UnknownFormat { file: "m.xyz".into(), ext: "xyz".into() }),
            Error::Mesh(_)
        ));
        assert!(matches!(kept(ModelBakeError::Resolution(0)), Error::ModelBake(_)));
        let range = crate::formats::tiles3d::AnchorRangeError::Latitude(95.0);
        assert!(matches!(kept(Tiles3dError::from(range)), Error::Tiles3d(_)));
        assert_eq!(
            Error::from(ExportError::Anchor { path: p(), source: range }).to_string(),
            "/x/y: anchor: latitude 95 is not within -90..90 degrees"
        );
        assert!(matches!(kept(ExportError::Exists { path: p() }), Error::Export(_)));
        #[cfg(feature = "gpu")]
        assert!(matches!(kept(crate::gpu::GpuError::NoAdapter), Error::Gpu(_)));
        #[cfg(feature = "server")]
        assert!(matches!(kept(crate::server::ServerError::Config("--bind: x".into())), Error::Server(_)));
        #[cfg(feature = "client")]
        {
            assert!(matches!(kept(crate::client::ClientError::NoGpuFeature), Error::Client(_)));
            assert!(matches!(kept(crate::eval::EvalError::Threshold(-1.0)), Error::Eval(_)));
        }
        // `?` converts too.
        let f = || -> Result<()> { Err(TinError::BadMaxError(f64::NAN))? };
        assert_eq!(f().unwrap_err().to_string(), "tin: max error must be finite and ≥ 0, got NaN");
    }
}
