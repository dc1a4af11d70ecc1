//! What a dataset is read through: a file (or a window of one) placed on the dataset grid
//! ([`Part`]), read in blocks by a [`BlockSource`]. Shared by the dataset and the warp, which
//! reads its files through parts too.

use std::path::{Path, PathBuf};

use super::RasterError;

/// Largest dataset side, in samples.
pub const MAX_DATASET_SIDE: u32 = 1 << 20;

/// Reads one file's samples in blocks: values as stored, no-data as NaN.
pub(super) trait BlockSource: Send + Sync {
    /// (width, height) of a block; blocks at the right and bottom edges are clipped.
    fn block_size(&self) -> (u32, u32);
    /// The clipped block (bx, by), row-major, appended to `out` (empty: a buffer the cache
    /// reuses).
    fn read_block(&self, path: &Path, bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError>;
}

/// One file placed on the dataset grid.
pub(super) struct Part {
    pub(super) path: PathBuf,
    pub(super) source: Box<dyn BlockSource>,
    pub(super) format: &'static str,
    /// Offset of its window's sample (0, 0) on the dataset grid, and the window's size.
    pub(super) col: u32,
    pub(super) row: u32,
    pub(super) width: u32,
    pub(super) height: u32,
    /// The window's offset within the file (a VRT source's `SrcRect`; else 0, 0), and the file's size.
    pub(super) win_col: u32,
    pub(super) win_row: u32,
    pub(super) file_width: u32,
    pub(super) file_height: u32,
    /// Further values that are no-data here (a VRT's `<NoDataValue>` and `<NODATA>`).
    pub(super) nodata: Vec<f32>,
}

/// A part that is a whole file.
pub(super) fn whole_part(
    path: &Path,
    source: Box<dyn BlockSource>,
    format: &'static str,
    width: u32,
    height: u32,
) -> Part {
    Part {
        path: path.to_owned(),
        source,
        format,
        col: 0,
        row: 0,
        width,
        height,
        win_col: 0,
        win_row: 0,
        file_width: width,
        file_height: height,
        nodata: Vec::new(),
    }
}
