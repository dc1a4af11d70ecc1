//! Object storage in a build without the `s3` feature: URLs are refused with a clear error.

use super::{Backend, Location};
use crate::store::StoreError;

/// The URL schemes this build opens: none.
pub const SCHEMES: &[&str] = &[];

/// Folder names, and object names with their sizes and last-modified times (Unix ms).
pub type Listing = (Vec<String>, Vec<(String, u64, i64)>);

/// Never constructed in this build.
#[derive(Debug, Clone)]
pub enum Bucket {}

impl Bucket {
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
    pub async fn get_async(&self, _: &str, _: u64) -> Result<Option<bytes::Bytes>, StoreError> {
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

impl Backend for Bucket {
    fn location(&self) -> &Location {
        match *self {}
    }
    fn read(&self, _: &str, _: u64) -> Result<Option<Vec<u8>>, StoreError> {
        match *self {}
    }
    fn size(&self, _: &str) -> Result<Option<u64>, StoreError> {
        match *self {}
    }
    fn exists(&self, _: &str) -> Result<bool, StoreError> {
        match *self {}
    }
    fn list(&self) -> Result<Vec<(String, u64)>, StoreError> {
        match *self {}
    }
    fn write(&self, _: &str, _: &[u8]) -> Result<(), StoreError> {
        match *self {}
    }
    fn remove(&self, _: &str) -> Result<(), StoreError> {
        match *self {}
    }
    fn remove_folder(&self, _: &str) -> Result<(), StoreError> {
        match *self {}
    }
    fn check_writable(&self) -> Result<(), StoreError> {
        match *self {}
    }
    fn create_first(&self, _: &str, _: &[u8]) -> Result<bool, StoreError> {
        match *self {}
    }
    #[cfg(feature = "server")]
    fn read_async<'a>(
        &'a self,
        _: &'a str,
        _: u64,
    ) -> super::BoxFuture<'a, Result<Option<bytes::Bytes>, StoreError>> {
        match *self {}
    }
    #[cfg(feature = "server")]
    fn exists_async<'a>(&'a self, _: &'a str) -> super::BoxFuture<'a, Result<bool, StoreError>> {
        match *self {}
    }
}

/// Never constructed in this build.
pub struct BucketSource(Bucket);

impl BucketSource {
    #[must_use]
    pub fn new(r: Bucket) -> Self {
        Self(r)
    }
}

impl crate::store::archive::RangeSource for BucketSource {
    fn read_range(&self, _: u64, _: u64) -> std::io::Result<Vec<u8>> {
        match self.0 {}
    }
}
