//! Tileset directory (work in progress).

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("store: {0}")]
    Invalid(String),
}
