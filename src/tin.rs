//! Greedy error-driven TIN (work in progress).

#[derive(Debug, thiserror::Error)]
pub enum TinError {
    #[error("tin: {0}")]
    Invalid(String),
}
