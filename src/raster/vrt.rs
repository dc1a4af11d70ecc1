//! GDAL VRT mosaics: the subset that places files on one grid without resampling.
//!
//! A VRT (`<VRTDataset>`) names its size, its `<GeoTransform>`, its CRS (`<SRS>`) and, in one
//! `<VRTRasterBand>`, the sources that paint it. Each `<SimpleSource>` (or a `<ComplexSource>`
//! that only declares a `<NODATA>` value) copies a `<SrcRect>` of a file into a `<DstRect>` of
//! the VRT. We accept exactly the sources that copy samples one to one: `SrcRect` and `DstRect`
//! of the same size at whole-sample offsets. Anything that would resample, rescale or compute
//! (other sizes, fractional offsets, scale/offset/LUT on a source, derived or warped datasets,
//! kernel and averaged sources) is refused, naming the element. A source's own georeference is
//! ignored (GDAL places it by its `DstRect` alone); its no-data and the band's `<NoDataValue>`
//! are both no-data. Parsing is pure: the caller reads the file and opens the sources.

use std::path::{Path, PathBuf};

use super::{FileCrs, FileGeoref, RasterError};

/// Largest VRT file read, in bytes.
pub const MAX_VRT_BYTES: u64 = 64 << 20;
/// Most sources one VRT may name.
pub const MAX_VRT_SOURCES: usize = 1 << 20;
/// Largest VRT side, in samples (the dataset's limit).
const MAX_SIDE: u64 = 1 << 20;

const FORMAT: &str = "GDAL VRT";

/// One source: a window of a file copied to a position on the VRT grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Source {
    pub file: PathBuf,
    /// Window of the file: column, row, width, height (already clipped to the VRT).
    pub src: (u32, u32, u32, u32),
    /// Where the window's sample (0, 0) lands on the VRT grid.
    pub dst: (u32, u32),
    /// Values that are no-data in this source (the band's and the source's own).
    pub nodata: Vec<f64>,
    /// The element, for messages ("SimpleSource #3").
    pub element: String,
    /// No `<SrcRect>`: the whole file is read, and it must have this size (the `DstRect`'s, before
    /// clipping), else GDAL would resample it.
    pub whole_file: Option<(u32, u32)>,
}

/// A parsed VRT.
#[derive(Debug, Clone, PartialEq)]
pub struct Vrt {
    pub width: u32,
    pub height: u32,
    /// Georeference of the VRT's sample (0, 0) centre.
    pub(crate) georef: FileGeoref,
    /// The `<SRS>`'s coordinate system (none without one).
    pub(crate) crs: FileCrs,
    pub sources: Vec<Source>,
}

fn unsupported(path: &Path, message: impl Into<String>) -> RasterError {
    RasterError::unsupported(path, FORMAT, message)
}

fn corrupt(path: &Path, message: impl Into<String>) -> RasterError {
    RasterError::corrupt(path, FORMAT, message)
}

/// Parses a VRT's text. `path` names the VRT in messages and resolves `relativeToVRT` names.
// Scale 1 and offset 0 are compared exactly: any other value changes the samples.
#[allow(clippy::float_cmp)]
pub fn parse(path: &Path, text: &str) -> Result<Vrt, RasterError> {
    let doc =
        roxmltree::Document::parse(text).map_err(|e| corrupt(path, format!("not well-formed XML: {e}")))?;
    let root = doc.root_element();
    if !root.has_tag_name("VRTDataset") {
        return Err(corrupt(
            path,
            format!("the root element is <{}>, not <VRTDataset>", root.tag_name().name()),
        ));
    }
    if let Some(sub) = root.attribute("subClass") {
        return Err(unsupported(
            path,
            format!(
                "<VRTDataset subClass=\"{sub}\"> warps or computes its samples; only mosaics of simple sources are read"
            ),
        ));
    }
    let size = |name: &str| -> Result<u32, RasterError> {
        let v = root.attribute(name).ok_or_else(|| corrupt(path, format!("<VRTDataset> has no {name}")))?;
        match v.trim().parse::<u64>() {
            Ok(n) if (1..=MAX_SIDE).contains(&n) => Ok(n as u32),
            _ => Err(corrupt(path, format!("<VRTDataset {name}=\"{v}\"> is not a size in 1..={MAX_SIDE}"))),
        }
    };
    let (width, height) = (size("rasterXSize")?, size("rasterYSize")?);
    let child = |name: &str| root.children().find(|n| n.has_tag_name(name));
    let gt_text = child("GeoTransform").and_then(|n| n.text()).ok_or_else(|| {
        unsupported(path, "has no <GeoTransform>; a VRT mosaic must say where its grid lies")
    })?;
    let gt: Vec<f64> =
        gt_text.split(',').map(|s| s.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| {
            corrupt(path, format!("<GeoTransform>{}</GeoTransform> is not six numbers", gt_text.trim()))
        })?;
    if gt.len() != 6 || gt.iter().any(|v| !v.is_finite()) {
        return Err(corrupt(
            path,
            format!("<GeoTransform>{}</GeoTransform> is not six finite numbers", gt_text.trim()),
        ));
    }
    if gt[2] != 0.0 || gt[4] != 0.0 {
        return Err(unsupported(
            path,
            format!(
                "<GeoTransform> is rotated or sheared ({}, {}); resample it to a north-up grid first",
                gt[2], gt[4]
            ),
        ));
    }
    if gt[1] == 0.0 || gt[5] == 0.0 {
        return Err(corrupt(path, "<GeoTransform> has a zero cell size"));
    }
    let srs = child("SRS").and_then(|n| n.text()).unwrap_or("").trim();
    let (x0, y0) = (gt[0] + 0.5 * gt[1], gt[3] + 0.5 * gt[5]);
    let crs = if srs.is_empty() {
        FileCrs::default()
    } else {
        let (horizontal, vertical) = crate::crs::Crs::parse(srs).map_err(|e| RasterError::Crs {
            path: path.to_owned(),
            message: format!("<SRS>{}</SRS>: {e}", srs.chars().take(120).collect::<String>()),
        })?;
        FileCrs { horizontal: Some(horizontal), vertical }
    };
    let georef = if crs.horizontal.as_ref().is_some_and(crate::crs::Crs::is_geographic) {
        FileGeoref::Geographic { lon0: x0, lat0: y0, dlon: gt[1], dlat: gt[5] }
    } else {
        FileGeoref::Projected { x0, y0, dx: gt[1], dy: gt[5] }
    };

    let bands: Vec<_> = root.children().filter(|n| n.has_tag_name("VRTRasterBand")).collect();
    let band = match bands.as_slice() {
        [b] => *b,
        [] => return Err(corrupt(path, "has no <VRTRasterBand>")),
        more => {
            return Err(unsupported(path, format!("has {} bands; a heightfield VRT has one", more.len())));
        }
    };
    if let Some(sub) = band.attribute("subClass") {
        return Err(unsupported(
            path,
            format!("<VRTRasterBand subClass=\"{sub}\"> computes its samples; only simple sources are read"),
        ));
    }
    let band_child = |name: &str| band.children().find(|n| n.has_tag_name(name)).and_then(|n| n.text());
    let number = |what: &str, v: &str| -> Result<f64, RasterError> {
        let t = v.trim();
        if t.eq_ignore_ascii_case("nan") {
            return Ok(f64::NAN);
        }
        t.parse::<f64>().map_err(|_| corrupt(path, format!("{what} \"{t}\" is not a number")))
    };
    for (name, identity) in [("Scale", 1.0), ("Offset", 0.0)] {
        if let Some(v) = band_child(name)
            && number(&format!("<{name}>"), v)? != identity
        {
            return Err(unsupported(
                path,
                format!(
                    "<VRTRasterBand> has <{name}>{}</{name}>; heights are read as stored, so pass --z-scale/--z-offset \
                     instead",
                    v.trim()
                ),
            ));
        }
    }
    let band_nodata = band_child("NoDataValue").map(|v| number("<NoDataValue>", v)).transpose()?;

    let base = path.parent().unwrap_or(Path::new(""));
    let mut sources = Vec::new();
    let mut counts = std::collections::HashMap::<&str, usize>::new();
    for node in band.children().filter(roxmltree::Node::is_element) {
        let kind = node.tag_name().name();
        let n = counts.entry(kind).or_insert(0);
        *n += 1;
        let element = format!("{kind} #{n}");
        match kind {
            "SimpleSource" | "ComplexSource" => {}
            "AveragedSource" | "KernelFilteredSource" | "NoDataFromMaskSource" | "ArraySource" => {
                return Err(unsupported(
                    path,
                    format!(
                        "<{kind}> (the {element}) resamples or computes; only SimpleSource and ComplexSource copy samples"
                    ),
                ));
            }
            _ => continue,
        }
        if sources.len() >= MAX_VRT_SOURCES {
            return Err(unsupported(path, format!("names more than {MAX_VRT_SOURCES} sources")));
        }
        let sub = |name: &str| node.children().find(|c| c.has_tag_name(name));
        let file_node = sub("SourceFilename")
            .ok_or_else(|| corrupt(path, format!("the {element} has no <SourceFilename>")))?;
        let name = file_node.text().map_or("", str::trim);
        if name.is_empty() {
            return Err(corrupt(path, format!("the {element} has an empty <SourceFilename>")));
        }
        if name.starts_with("/vsi") {
            return Err(unsupported(
                path,
                format!(
                    "the {element} reads {name}: GDAL virtual file systems are not read; name a local file"
                ),
            ));
        }
        let relative = file_node.attribute("relativeToVRT").is_some_and(|v| v.trim() == "1");
        let file = if relative { base.join(name) } else { PathBuf::from(name) };
        if let Some(b) = sub("SourceBand").and_then(|n| n.text())
            && b.trim() != "1"
        {
            return Err(unsupported(
                path,
                format!("the {element} reads band {} of {name}; heightfields are read from band 1", b.trim()),
            ));
        }
        let mut nodata: Vec<f64> = band_nodata.into_iter().collect();
        if kind == "ComplexSource" {
            for c in node.children().filter(roxmltree::Node::is_element) {
                let cname = c.tag_name().name();
                let text = c.text().unwrap_or("");
                let changes = match cname {
                    "ScaleOffset" => number("<ScaleOffset>", text)? != 0.0,
                    "ScaleRatio" => number("<ScaleRatio>", text)? != 1.0,
                    "LUT" | "ColorTableComponent" | "Exponent" => true,
                    "NODATA" => {
                        nodata.push(number("<NODATA>", text)?);
                        false
                    }
                    _ => false,
                };
                if changes {
                    return Err(unsupported(
                        path,
                        format!(
                            "the {element} has <{cname}>{}</{cname}>, which changes the samples it copies; heights are \
                             read as stored",
                            text.trim()
                        ),
                    ));
                }
            }
        }
        let rect = |name: &str| -> Result<Option<[f64; 4]>, RasterError> {
            let Some(r) = sub(name) else { return Ok(None) };
            let mut v = [0.0; 4];
            for (slot, attr) in v.iter_mut().zip(["xOff", "yOff", "xSize", "ySize"]) {
                let a = r
                    .attribute(attr)
                    .ok_or_else(|| corrupt(path, format!("the {element}'s <{name}> has no {attr}")))?;
                *slot =
                    a.trim().parse::<f64>().ok().filter(|x| x.is_finite() && x.abs() <= 1e12).ok_or_else(
                        || corrupt(path, format!("the {element}'s <{name} {attr}=\"{a}\"> is not a number")),
                    )?;
            }
            Ok(Some(v))
        };
        let src = rect("SrcRect")?;
        let whole_file = src.is_none();
        let dst = rect("DstRect")?.unwrap_or([0.0, 0.0, f64::from(width), f64::from(height)]);
        // Without a SrcRect GDAL reads the whole file; its size is known only once opened, so the
        // source keeps the DstRect's size and the caller checks it against the file.
        let src = src.unwrap_or([0.0, 0.0, dst[2], dst[3]]);
        let whole = |v: f64| (v - v.round()).abs() <= 1e-6;
        if (src[2] - dst[2]).abs() > 1e-6 || (src[3] - dst[3]).abs() > 1e-6 {
            return Err(unsupported(
                path,
                format!(
                    "the {element} ({name}) maps a {}×{} SrcRect onto a {}×{} DstRect, which needs resampling; only \
                     one-to-one copies are read (resample it with gdalwarp first)",
                    src[2], src[3], dst[2], dst[3]
                ),
            ));
        }
        if !src.iter().chain(&dst).all(|&v| whole(v)) {
            return Err(unsupported(
                path,
                format!(
                    "the {element} ({name}) has fractional offsets or sizes (SrcRect {src:?}, DstRect {dst:?}), which \
                     need resampling"
                ),
            ));
        }
        if src[2] < 1.0 || src[3] < 1.0 || src[2] > MAX_SIDE as f64 || src[3] > MAX_SIDE as f64 {
            return Err(corrupt(
                path,
                format!("the {element} ({name}) has a SrcRect of {}×{} samples", src[2], src[3]),
            ));
        }
        let whole_file = whole_file.then(|| (src[2].round() as u32, src[3].round() as u32));
        // Clip to the VRT (GDAL draws only what falls inside) and to non-negative source offsets.
        let (mut sx, mut sy, mut dx, mut dy) =
            (src[0].round(), src[1].round(), dst[0].round(), dst[1].round());
        let (mut w, mut h) = (src[2].round(), src[3].round());
        for (s, d, len, limit) in
            [(&mut sx, &mut dx, &mut w, f64::from(width)), (&mut sy, &mut dy, &mut h, f64::from(height))]
        {
            let cut = (-*d).max(-*s).max(0.0);
            *s += cut;
            *d += cut;
            *len -= cut;
            *len = len.min(limit - *d);
        }
        if w < 1.0 || h < 1.0 {
            continue; // entirely outside the VRT: paints nothing
        }
        sources.push(Source {
            file,
            src: (sx as u32, sy as u32, w as u32, h as u32),
            dst: (dx as u32, dy as u32),
            nodata,
            element,
            whole_file,
        });
    }
    if sources.is_empty() {
        return Err(corrupt(path, "its band has no source inside the VRT's extent"));
    }
    Ok(Vrt { width, height, georef, crs, sources })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vrt(band: &str) -> String {
        format!(
            r#"<VRTDataset rasterXSize="20" rasterYSize="10">
  <SRS>PROJCS["WGS 84 / UTM zone 33N",GEOGCS["WGS 84"],AUTHORITY["EPSG","32633"]]</SRS>
  <GeoTransform> 1000.0, 2.0, 0.0, 5000.0, 0.0, -2.0</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">{band}</VRTRasterBand>
</VRTDataset>"#
        )
    }

    fn parse_str(s: &str) -> Result<Vrt, RasterError> {
        parse(Path::new("/data/m.vrt"), s)
    }

    #[test]
    fn simple_sources_place_windows() {
        let v = parse_str(&vrt(r#"<NoDataValue>-9999</NoDataValue>
            <SimpleSource><SourceFilename relativeToVRT="1">a.tif</SourceFilename><SourceBand>1</SourceBand>
              <SrcRect xOff="0" yOff="0" xSize="10" ySize="10"/><DstRect xOff="0" yOff="0" xSize="10" ySize="10"/></SimpleSource>
            <ComplexSource><SourceFilename relativeToVRT="0">/abs/b.tif</SourceFilename><NODATA>0</NODATA><ScaleRatio>1</ScaleRatio>
              <SrcRect xOff="5" yOff="2" xSize="12" ySize="8"/><DstRect xOff="10" yOff="2" xSize="12" ySize="8"/></ComplexSource>"#))
        .unwrap();
        assert_eq!((v.width, v.height), (20, 10));
        assert_eq!(v.georef, FileGeoref::Projected { x0: 1001.0, y0: 4999.0, dx: 2.0, dy: -2.0 });
        assert_eq!(v.sources[0].file, PathBuf::from("/data/a.tif"));
        assert_eq!((v.sources[0].src, v.sources[0].dst), ((0, 0, 10, 10), (0, 0)));
        assert_eq!(v.sources[0].nodata, vec![-9999.0]);
        // Clipped at the VRT's right edge: 12 columns from 10 leave 10.
        assert_eq!(v.sources[1].file, PathBuf::from("/abs/b.tif"));
        assert_eq!((v.sources[1].src, v.sources[1].dst), ((5, 2, 10, 8), (10, 2)));
        assert_eq!(v.sources[1].nodata, vec![-9999.0, 0.0]);
    }

    #[test]
    fn geographic_srs_and_negative_offsets() {
        let s = vrt(r#"<SimpleSource><SourceFilename>t.hgt</SourceFilename>
              <SrcRect xOff="0" yOff="0" xSize="30" ySize="30"/><DstRect xOff="-3" yOff="-4" xSize="30" ySize="30"/></SimpleSource>"#)
        .replace(
            r#"PROJCS["WGS 84 / UTM zone 33N",GEOGCS["WGS 84"],AUTHORITY["EPSG","32633"]]"#,
            r#"GEOGCS["WGS 84",DATUM["WGS_1984"],AUTHORITY["EPSG","4326"]]"#,
        );
        let v = parse_str(&s).unwrap();
        assert!(matches!(v.georef, FileGeoref::Geographic { .. }));
        assert_eq!((v.sources[0].src, v.sources[0].dst), ((3, 4, 20, 10), (0, 0)));
        assert_eq!(v.crs.horizontal.as_ref().and_then(crate::crs::Crs::epsg), Some(4326));
        // An SRS that names no EPSG identifier is refused, naming the element.
        let e = parse_str(&s.replace(r#"AUTHORITY["EPSG","4326"]"#, "")).unwrap_err().to_string();
        assert!(e.contains("<SRS>") && e.contains("coordinate system"), "{e}");
    }

    #[test]
    fn resampling_and_computing_refused_naming_the_element() {
        let cases = [
            (
                r#"<SimpleSource><SourceFilename>a.tif</SourceFilename><SrcRect xOff="0" yOff="0" xSize="20" ySize="20"/><DstRect xOff="0" yOff="0" xSize="10" ySize="10"/></SimpleSource>"#,
                "SimpleSource #1",
            ),
            (
                r#"<SimpleSource><SourceFilename>a.tif</SourceFilename><SrcRect xOff="0" yOff="0" xSize="4" ySize="4"/><DstRect xOff="0" yOff="0" xSize="4" ySize="4"/></SimpleSource>
                   <SimpleSource><SourceFilename>b.tif</SourceFilename><SrcRect xOff="0.5" yOff="0" xSize="4" ySize="4"/><DstRect xOff="4" yOff="0" xSize="4" ySize="4"/></SimpleSource>"#,
                "SimpleSource #2",
            ),
            ("<AveragedSource><SourceFilename>a.tif</SourceFilename></AveragedSource>", "AveragedSource"),
            (
                "<ComplexSource><SourceFilename>a.tif</SourceFilename><ScaleRatio>0.1</ScaleRatio></ComplexSource>",
                "ScaleRatio",
            ),
            ("<Scale>0.1</Scale>", "<Scale>"),
            (
                "<SimpleSource><SourceFilename>a.tif</SourceFilename><SourceBand>2</SourceBand></SimpleSource>",
                "band 2",
            ),
        ];
        for (band, needle) in cases {
            let e = parse_str(&vrt(band)).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("m.vrt"), "{needle}: {e}");
        }
        for (text, needle) in [
            ("<VRTDataset", "XML"),
            ("<Foo/>", "VRTDataset"),
            (r#"<VRTDataset rasterXSize="0" rasterYSize="1"/>"#, "rasterXSize"),
            (r#"<VRTDataset rasterXSize="2" rasterYSize="1"/>"#, "GeoTransform"),
            (
                r#"<VRTDataset subClass="VRTWarpedDataset" rasterXSize="2" rasterYSize="1"/>"#,
                "VRTWarpedDataset",
            ),
        ] {
            let e = parse_str(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
        }
        let rotated = vrt("").replace("0.0, 5000.0, 0.0", "0.5, 5000.0, 0.0");
        assert!(parse_str(&rotated).unwrap_err().to_string().contains("rotated"));
    }
}
