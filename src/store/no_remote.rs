//! Object storage in a build without the `s3` feature: URLs are refused with a clear error.

use super::StoreError;

/// The URL schemes this build opens: none.
pub const SCHEMES: &[&str] = &[];

/// Whether `location` names object storage (a URL with a scheme other than `file://`).
#[must_use]
pub fn is_remote(location: &str) -> bool {
    location.contains("://") && !location.starts_with("file://")
}

/// Folder names, and object names with their sizes and last-modified times (Unix ms).
pub type Listing = (Vec<String>, Vec<(String, u64, i64)>);

/// Never constructed in this build.
#[derive(Debug, Clone)]
pub enum Remote {}

impl Remote {
    pub fn open(url: &str) -> Result<Self, StoreError> {
        Err(StoreError::Remote {
            url: url.to_owned(),
            message: "this build has no object storage (build with the `s3` feature)".into(),
        })
    }
    #[must_use]
    pub fn url(&self) -> &str {
        match *self {}
    }
    pub fn get(&self, _: &str) -> Result<Option<Vec<u8>>, StoreError> {
        match *self {}
    }
    pub fn put(&self, _: &str, _: &[u8]) -> Result<(), StoreError> {
        match *self {}
    }
    pub fn put_new(&self, _: &str, _: &[u8]) -> Result<bool, StoreError> {
        match *self {}
    }
    pub fn delete(&self, _: &str) -> Result<(), StoreError> {
        match *self {}
    }
    pub fn exists(&self, _: &str) -> Result<bool, StoreError> {
        match *self {}
    }
    pub fn list(&self, _: &str) -> Result<Vec<(String, u64)>, StoreError> {
        match *self {}
    }
    pub fn is_empty(&self) -> Result<bool, StoreError> {
        match *self {}
    }
    pub fn delete_folder(&self, _: &str) -> Result<(), StoreError> {
        match *self {}
    }
    pub fn size(&self, _: &str) -> Result<Option<u64>, StoreError> {
        match *self {}
    }
    pub fn put_file(&self, _: &str, _: &std::path::Path) -> Result<(), StoreError> {
        match *self {}
    }
    #[must_use]
    pub fn child(&self, _: &str) -> Self {
        match *self {}
    }
    #[cfg(feature = "server")]
    pub async fn get_async(&self, _: &str) -> Result<Option<bytes::Bytes>, StoreError> {
        match *self {}
    }
    #[cfg(feature = "server")]
    pub async fn exists_async(&self, _: &str) -> Result<bool, StoreError> {
        match *self {}
    }
    pub fn list_top(&self) -> Result<Listing, StoreError> {
        match *self {}
    }
    pub fn stamp(&self, _: &str) -> Result<Option<(u64, i64)>, StoreError> {
        match *self {}
    }
}

/// Never constructed in this build.
pub struct RemoteSource(Remote);

impl RemoteSource {
    #[must_use]
    pub fn new(r: Remote) -> Self {
        Self(r)
    }
}

impl super::archive::RangeSource for RemoteSource {
    fn read_range(&self, _: u64, _: u64) -> std::io::Result<Vec<u8>> {
        match self.0 {}
    }
}
