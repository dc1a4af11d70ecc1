//! Vertical datums and geoid grids: what a height means ([`VerticalDatum`]) and the undulation
//! `N` that turns an orthometric height `H` into an ellipsoidal one, `h = H + N`.
//!
//! EGM96 ships inside the binary ([`Geoid::egm96`]): the NGA's 15′ grid (public domain, as
//! Debian's `proj-data` ships it in `/usr/share/proj/egm96_15.gtx`), packed by
//! `tools/geoid/pack_egm96.py` to whole centimetres (≤ 0.5 cm off the grid's values). Other grids
//! (EGM2008, national geoids) are read from a GTX file ([`Geoid::from_gtx`]). Undulations are
//! interpolated bilinearly between grid nodes; against the full model, EGM96's 15′ grid
//! interpolates to within a few centimetres in flat regions and ~0.3 m in the steepest
//! mountains (NGA's figures for the 15′ grid), which is the bound stated for it.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use serde::{Deserialize, Serialize};

/// What the heights of a dataset are measured from.
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VerticalDatum {
    /// Heights above the WGS 84 ellipsoid, whatever the horizontal datum: heights that name no
    /// datum are taken as-is (not moved by the horizontal datum shift's tens of metres, which
    /// would apply only to heights truly above another ellipsoid).
    Ellipsoid,
    /// Orthometric heights above the EGM96 geoid (SRTM, most DEMs of the 2000s; EPSG:5773).
    Egm96,
    /// Orthometric heights above the EGM2008 geoid (EPSG:3855): needs a grid file.
    Egm2008,
}

impl VerticalDatum {
    /// Its name as `--vertical-datum` takes it and the manifest records it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Ellipsoid => "ellipsoid",
            Self::Egm96 => "egm96",
            Self::Egm2008 => "egm2008",
        }
    }

    /// The datum of a GeoTIFF `VerticalCSTypeGeoKey` / EPSG vertical CRS code, when it is one of
    /// ours.
    #[must_use]
    pub fn from_epsg(code: u32) -> Option<Self> {
        match code {
            5773 => Some(Self::Egm96),
            3855 => Some(Self::Egm2008),
            // WGS 84 ellipsoidal heights (EPSG:4979's vertical axis; 4326 used as a vertical code).
            4979 | 4326 => Some(Self::Ellipsoid),
            _ => None,
        }
    }
}

/// Why a geoid grid cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum GeoidError {
    #[error("{}: cannot read geoid grid: {source}", path.display())]
    Io { path: std::path::PathBuf, source: std::io::Error },
    #[error("{}: not a GTX geoid grid: {message}", path.display())]
    Format { path: std::path::PathBuf, message: String },
    #[error("the embedded EGM96 grid is damaged: {0}")]
    Embedded(String),
}

/// Largest grid accepted from a file, in nodes (EGM2008 at 1′ is 21,601 × 10,801 ≈ 2.3·10⁸).
pub const MAX_GRID_NODES: u64 = 240_000_000;

/// A geoid grid: undulations in metres on a regular lon/lat grid, south row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Geoid {
    /// What it is, for the manifest: "EGM96 15′ (embedded)" or the file's name.
    pub name: String,
    lat0: f64,
    lon0: f64,
    dlat: f64,
    dlon: f64,
    rows: usize,
    cols: usize,
    /// True when the columns go once around the globe (the last column wraps to the first).
    wraps: bool,
    values: Vec<f32>,
}

static EGM96: OnceLock<Result<Arc<Geoid>, String>> = OnceLock::new();

impl Geoid {
    /// The embedded EGM96 15′ grid (decoded once per process).
    pub fn egm96() -> Result<Arc<Self>, GeoidError> {
        EGM96
            .get_or_init(|| Self::from_packed(include_bytes!("egm96_15.tsg")).map(Arc::new))
            .clone()
            .map_err(GeoidError::Embedded)
    }

    fn from_packed(bytes: &[u8]) -> Result<Self, String> {
        let head = bytes.get(..48).ok_or("short header")?;
        if &head[..8] != b"TSGEOID1" {
            return Err("bad magic".into());
        }
        let f = |i: usize| f64::from_le_bytes(head[8 + 8 * i..16 + 8 * i].try_into().unwrap_or_default());
        let u = |o: usize| u32::from_le_bytes(head[o..o + 4].try_into().unwrap_or_default()) as usize;
        let (lat0, lon0, dlat, dlon, rows, cols) = (f(0), f(1), f(2), f(3), u(40), u(44));
        let n = rows.checked_mul(cols).filter(|&n| n > 0 && n as u64 <= MAX_GRID_NODES).ok_or("bad size")?;
        let raw = zstd::bulk::decompress(&bytes[48..], n * 2).map_err(|e| e.to_string())?;
        if raw.len() != n * 2 {
            return Err("short payload".into());
        }
        let d2: Vec<i64> = raw.chunks_exact(2).map(|c| i64::from(i16::from_le_bytes([c[0], c[1]]))).collect();
        // Undo the differences: down the columns, then along each row.
        let mut d = d2;
        for r in 1..rows {
            for c in 0..cols {
                d[r * cols + c] += d[(r - 1) * cols + c];
            }
        }
        for r in 0..rows {
            for c in 1..cols {
                d[r * cols + c] += d[r * cols + c - 1];
            }
        }
        let values = d.iter().map(|&cm| cm as f32 / 100.0).collect();
        Ok(Self::assemble(
            "EGM96 15′ (embedded, whole cm)".into(),
            lat0,
            lon0,
            dlat,
            dlon,
            rows,
            cols,
            values,
        ))
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        name: String,
        lat0: f64,
        lon0: f64,
        dlat: f64,
        dlon: f64,
        rows: usize,
        cols: usize,
        values: Vec<f32>,
    ) -> Self {
        let wraps = ((cols as f64) * dlon - 360.0).abs() < dlon * 1e-6;
        Self { name, lat0, lon0, dlat, dlon, rows, cols, wraps, values }
    }

    /// Reads a GTX grid (NOAA's format, as PROJ ships them): four big-endian f64 (south-west
    /// latitude, longitude, Δlatitude, Δlongitude, degrees), two big-endian i32 (rows, columns),
    /// then rows × columns big-endian f32 undulations in metres, south row first; −88.8888 marks
    /// a node without a value.
    pub fn from_gtx(path: &Path) -> Result<Self, GeoidError> {
        use std::io::Read;
        let bad = |message: String| GeoidError::Format { path: path.to_owned(), message };
        let io = |source| GeoidError::Io { path: path.to_owned(), source };
        // A FIFO's open would wait for a writer forever, and a device never ends: refused by
        // type, unopened (the grid's size is checked against its header below).
        let not_file = |md: &std::fs::Metadata| {
            (!md.is_file()).then(|| bad("not a regular file (a FIFO, a device or a directory)".into()))
        };
        if let Some(e) = not_file(&std::fs::metadata(path).map_err(io)?) {
            return Err(e);
        }
        let mut file = std::fs::File::open(path).map_err(io)?;
        if let Some(e) = not_file(&file.metadata().map_err(io)?) {
            return Err(e);
        }
        let mut head = [0u8; 40];
        file.read_exact(&mut head).map_err(io)?;
        let f = |i: usize| f64::from_be_bytes(head[8 * i..8 * i + 8].try_into().unwrap_or_default());
        let (lat0, mut lon0, dlat, dlon) = (f(0), f(1), f(2), f(3));
        let rows = i32::from_be_bytes([head[32], head[33], head[34], head[35]]);
        let cols = i32::from_be_bytes([head[36], head[37], head[38], head[39]]);
        if rows < 2 || cols < 2 || !(dlat > 0.0 && dlon > 0.0 && dlat.is_finite() && dlon.is_finite()) {
            return Err(bad(format!("{rows} rows × {cols} columns, steps {dlat}° × {dlon}°")));
        }
        if !(lat0.is_finite()
            && lon0.is_finite()
            && lat0 >= -90.0
            && lat0 + dlat * f64::from(rows - 1) <= 90.0 + 1e-9)
        {
            return Err(bad(format!("latitudes from {lat0}° by {dlat}° over {rows} rows leave ±90°")));
        }
        let n = u64::from(rows as u32) * u64::from(cols as u32);
        if n > MAX_GRID_NODES {
            return Err(bad(format!("{n} nodes; at most {MAX_GRID_NODES} are read")));
        }
        let len = file.metadata().map_err(io)?.len();
        if len != 40 + n * 4 {
            return Err(bad(format!("{len} bytes; a {rows}×{cols} grid has {}", 40 + n * 4)));
        }
        let mut raw = Vec::with_capacity(n as usize * 4);
        // Exactly the grid's bytes, even if the file grew since its size was read.
        (&mut file).take(n * 4).read_to_end(&mut raw).map_err(io)?;
        if raw.len() as u64 != n * 4 {
            return Err(bad(format!("{} bytes of values; a {rows}×{cols} grid has {}", raw.len(), n * 4)));
        }
        let values = raw
            .chunks_exact(4)
            .map(|c| {
                let v = f32::from_be_bytes([c[0], c[1], c[2], c[3]]);
                if (v + 88.8888).abs() < 1e-3 { f32::NAN } else { v }
            })
            .collect();
        if lon0 >= 180.0 {
            lon0 -= 360.0;
        }
        let name =
            path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        Ok(Self::assemble(name, lat0, lon0, dlat, dlon, rows as usize, cols as usize, values))
    }

    /// The undulation at (`lon`, `lat`) degrees, bilinear between the four nodes around it;
    /// `None` outside the grid or where a node has no value.
    #[must_use]
    pub fn undulation(&self, lon: f64, lat: f64) -> Option<f64> {
        if !(lon.is_finite() && lat.is_finite()) {
            return None;
        }
        let fr = ((lat - self.lat0) / self.dlat).clamp(-1.0, self.rows as f64);
        if fr < -1e-9 || fr > (self.rows - 1) as f64 + 1e-9 {
            return None;
        }
        let fr = fr.clamp(0.0, (self.rows - 1) as f64);
        let mut fc = (lon - self.lon0) / self.dlon;
        if self.wraps {
            fc = fc.rem_euclid(self.cols as f64);
        } else if fc < -1e-9 || fc > (self.cols - 1) as f64 + 1e-9 {
            return None;
        } else {
            fc = fc.clamp(0.0, (self.cols - 1) as f64);
        }
        let (r0, c0) = (fr.floor() as usize, fc.floor() as usize);
        let (tr, tc) = (fr - r0 as f64, fc - c0 as f64);
        let r1 = (r0 + 1).min(self.rows - 1);
        let c1 = if self.wraps { (c0 + 1) % self.cols } else { (c0 + 1).min(self.cols - 1) };
        let v = |r: usize, c: usize| f64::from(self.values[r * self.cols + c]);
        let top = v(r0, c0) * (1.0 - tc) + v(r0, c1) * tc;
        let bottom = v(r1, c0) * (1.0 - tc) + v(r1, c1) * tc;
        let n = top * (1.0 - tr) + bottom * tr;
        n.is_finite().then_some(n)
    }

    /// The smallest and largest node value (metres) over the nodes around a lon/lat box, for
    /// bounding heights; `None` when the box leaves the grid.
    #[must_use]
    pub fn range(&self, west: f64, south: f64, east: f64, north: f64) -> Option<(f64, f64)> {
        let r0 = ((south - self.lat0) / self.dlat).floor().max(0.0) as usize;
        let r1 = (((north - self.lat0) / self.dlat).ceil().max(0.0) as usize).min(self.rows - 1);
        let span = if east >= west { east - west } else { east + 360.0 - west };
        let c_start = ((west - self.lon0) / self.dlon).floor();
        let n_cols = ((span / self.dlon).ceil() as usize + 2).min(self.cols + 1);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for r in r0.min(self.rows - 1)..=r1 {
            for k in 0..n_cols {
                let c = c_start + k as f64;
                let c = if self.wraps {
                    c.rem_euclid(self.cols as f64) as usize
                } else if c < 0.0 || c >= self.cols as f64 {
                    continue;
                } else {
                    c as usize
                };
                let v = f64::from(self.values[r * self.cols + c]);
                if v.is_finite() {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
        }
        (lo <= hi).then_some((lo, hi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_egm96_matches_published_values() {
        let g = Geoid::egm96().unwrap();
        // NGA's EGM96 15' grid nodes (checked against /usr/share/proj/egm96_15.gtx with PROJ).
        // Node values: the packing keeps whole centimetres.
        for (lon, lat, n) in [(0.0, 0.0, 17.16), (-180.0, -90.0, -29.53), (0.0, 90.0, 13.61)] {
            let v = g.undulation(lon, lat).unwrap();
            assert!((v - n).abs() < 0.01, "{lon} {lat}: {v} vs {n}");
        }
        // The wrap: 179.9° E interpolates towards −180°.
        let a = g.undulation(179.9, 10.0).unwrap();
        let b = g.undulation(-180.1, 10.0).unwrap();
        assert!((a - b).abs() < 1e-9);
        assert!(g.undulation(f64::NAN, 0.0).is_none());
        assert!(g.undulation(0.0, 91.0).is_none());
    }

    /// A FIFO (an open waits for a writer forever) and a device are refused unopened.
    #[test]
    fn gtx_fifos_and_devices_are_refused_unopened() {
        let dir = tempfile::tempdir().unwrap();
        let zero = dir.path().join("zero.gtx");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        let e = Geoid::from_gtx(&zero).unwrap_err().to_string();
        assert!(e.contains("zero.gtx: not a GTX geoid grid: not a regular file"), "{e}");
        let fifo = dir.path().join("pipe.gtx");
        if !std::process::Command::new("mkfifo").arg(&fifo).status().is_ok_and(|s| s.success()) {
            return;
        }
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || tx.send(Geoid::from_gtx(&fifo).map(|_| ()).map_err(|e| e.to_string())));
        let e = rx.recv_timeout(std::time::Duration::from_secs(10)).expect("from_gtx waited on the FIFO");
        assert!(e.unwrap_err().contains("pipe.gtx: not a GTX geoid grid: not a regular file"));
    }

    #[test]
    fn gtx_round_trip_and_refusals() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.gtx");
        let mut b = Vec::new();
        for v in [10.0f64, 20.0, 1.0, 1.0] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        b.extend_from_slice(&2i32.to_be_bytes());
        b.extend_from_slice(&3i32.to_be_bytes());
        for v in [1.0f32, 2.0, 3.0, 4.0, 5.0, -88.8888] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        std::fs::write(&p, &b).unwrap();
        let g = Geoid::from_gtx(&p).unwrap();
        assert_eq!(g.undulation(20.5, 10.5), Some(3.0));
        assert_eq!(g.undulation(21.5, 10.5), None, "a node without a value");
        assert_eq!(g.undulation(19.0, 10.5), None, "outside");
        std::fs::write(&p, &b[..50]).unwrap();
        let e = Geoid::from_gtx(&p).unwrap_err().to_string();
        assert!(e.contains("g.gtx") && e.contains("bytes"), "{e}");
    }
}
