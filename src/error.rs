//! The library's error type: one enum per stage, gathered here so callers can match on the
//! stage that failed while `?` converts between them.

use crate::{
    bake::BakeError, bake::model_tileset::ModelBakeError, codec::CodecError, model::MeshError,
    raster::RasterError, store::StoreError, tin::TinError,
};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error(transparent)]
    Tin(#[from] TinError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Bake(#[from] BakeError),
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    ModelBake(#[from] ModelBakeError),
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
