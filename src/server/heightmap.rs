//! Heightmap tiles of every placed tileset on the Web-Mercator XYZ grid:
//! `/tilesets/{name}/heightmap/tiles.json` (TileJSON: bounds, zooms, encoding, tile URLs — what
//! MapLibre GL's `raster-dem` source takes as `url`) and `/tilesets/{name}/heightmap/{z}/{x}/{y}.png`
//! (`?encoding=terrarium|terrain-rgb`) or `{y}.f32` (float32). Heights come from the heights
//! samplers: the TIN a client draws at the tile's scale (`surface=mesh`, the default: the nodes
//! whose cells are no larger than the tile's pixels) or the source raster (`surface=source`),
//! above the EGM96 geoid by default (what these encodings carry), made on request and cached.

use std::sync::Arc;

use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderMap, HeaderValue, Method, header};
use axum::response::Response;
use bytes::Bytes;

use super::App;
use super::cache::Entry;
use super::conditional::{Conditional, etag_value, send};
use super::heights::{Sampler, Surface, chunk, sampler};
use super::loaders::{SHORT, parse_num, tileset, versioned_cache};
use super::problem::Problem;
use super::registry::{Tileset, etag_of};
use crate::formats::heightmap::{self as hm, Encoding, MAX_ZOOM, TILE_PX, Xyz};
use crate::heights::{Coords, Datum, Interp, Query};
use crate::tiling::TileKey;

/// Cache documents: `HM + variant` of a tile.
const HM: u16 = 0x300;

/// What a heightmap request asks for.
#[derive(Debug, Clone, Copy)]
struct Ask {
    encoding: Encoding,
    surface: Surface,
    datum: Datum,
}

impl Ask {
    fn parse(raw: Option<&str>) -> Result<Self, Problem> {
        let mut ask = Self {
            encoding: Encoding::Terrarium,
            surface: Surface::Mesh { depth: None },
            datum: Datum::Geoid,
        };
        for pair in raw.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
            let bad = |what: &str| Problem::bad_request(format!("query parameter {k}={v:?}: {what}"));
            match k {
                "encoding" => {
                    ask.encoding = Encoding::parse(v).ok_or_else(|| bad("use terrarium or terrain-rgb"))?;
                }
                "surface" => {
                    ask.surface = match v {
                        "mesh" => Surface::Mesh { depth: None },
                        "source" => Surface::Source,
                        _ => return Err(bad("use mesh or source")),
                    };
                }
                "datum" => {
                    ask.datum = match v {
                        "geoid" => Datum::Geoid,
                        "ellipsoid" => Datum::Ellipsoid,
                        "native" => Datum::Native,
                        _ => return Err(bad("use geoid, ellipsoid or native")),
                    };
                }
                "v" => {}
                _ => {
                    return Err(Problem::bad_request(format!(
                        "unknown query parameter {k:?}: use encoding, surface, datum"
                    )));
                }
            }
        }
        Ok(ask)
    }

    fn variant(self, f32_form: bool) -> u16 {
        let enc = u16::from(self.encoding == Encoding::TerrainRgb);
        let surface = u16::from(self.surface == Surface::Source);
        let datum = match self.datum {
            Datum::Geoid => 0,
            Datum::Ellipsoid => 1,
            Datum::Native => 2,
        };
        HM + enc + 2 * surface + 4 * datum + 16 * u16::from(f32_form)
    }
}

/// Where a placed tileset lies: its region (west, south, east, north in degrees; west > east
/// across the antimeridian), its cell size (metres) and the latitude of its centre.
struct Extent {
    west: f64,
    south: f64,
    east: f64,
    north: f64,
    cell_m: f64,
    lat: f64,
}

fn extent(ts: &Tileset) -> Result<Extent, Problem> {
    let region = ts.summary["globe"]["region"].as_array().filter(|r| r.len() >= 4).ok_or_else(|| {
        Problem::new(
            axum::http::StatusCode::CONFLICT,
            "not-placed",
            format!(
                "tileset {:?} is not placed on the Earth (no CRS): heightmap tiles need a georeferenced dataset",
                ts.name
            ),
        )
    })?;
    let r: Vec<f64> = region.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect();
    let m: crate::store::Manifest = serde_json::from_slice(&ts.manifest_json).map_err(|_| {
        Problem::internal("heightmap", format!("the manifest of {:?} cannot be read", ts.name))
    })?;
    let cell_m = m.frame.dx.abs().min(m.frame.dy.abs());
    Ok(Extent { west: r[0], south: r[1], east: r[2], north: r[3], cell_m, lat: f64::midpoint(r[1], r[3]) })
}

impl Extent {
    fn max_zoom(&self) -> u8 {
        hm::zoom_for_cell(self.cell_m, self.lat)
    }

    /// Whether tile `t` meets the data.
    fn meets(&self, t: Xyz) -> bool {
        let (w, s, e, n) = t.bounds();
        if s > self.north || n < self.south {
            return false;
        }
        let overlaps = |a: f64, b: f64| w <= b && e >= a;
        if self.west <= self.east {
            overlaps(self.west, self.east)
        } else {
            overlaps(self.west, 180.0) || overlaps(-180.0, self.east)
        }
    }
}

pub(super) async fn tilejson(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    RawQuery(query): RawQuery,
    method: Method,
    conditional: Conditional,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let ask = Ask::parse(query.as_deref())?;
    let ext = extent(&ts)?;
    let surface = if ask.surface == Surface::Source { "&surface=source" } else { "" };
    let datum = match ask.datum {
        Datum::Geoid => "",
        Datum::Ellipsoid => "&datum=ellipsoid",
        Datum::Native => "&datum=native",
    };
    let enc = if ask.encoding == Encoding::Terrarium { "terrarium" } else { "terrain-rgb" };
    // Absolute, as TileJSON readers expect: the host asked for, behind a proxy its scheme.
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("127.0.0.1");
    let scheme = headers
        .get("x-forwarded-proto")
        .and_then(|h| h.to_str().ok())
        .filter(|p| *p == "https")
        .unwrap_or("http");
    let url = format!(
        "{scheme}://{host}/tilesets/{name}/heightmap/{{z}}/{{x}}/{{y}}.png?encoding={enc}{surface}{datum}&v={}",
        ts.content_version
    );
    let doc = serde_json::json!({
        "tilejson": "3.0.0",
        "name": name,
        "scheme": "xyz",
        "tiles": [url],
        "minzoom": 0,
        "maxzoom": ext.max_zoom(),
        "bounds": [ext.west, ext.south.max(-hm::MAX_LAT), ext.east, ext.north.min(hm::MAX_LAT)],
        "tileSize": TILE_PX,
        "encoding": ask.encoding.maplibre_name(),
    });
    let body = serde_json::to_vec_pretty(&doc).unwrap_or_default();
    let entry = Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) };
    Ok(send(&method, &conditional, &entry, "application/json", SHORT))
}

type TilePath = (String, String, String, String);

pub(super) async fn tile(
    State(app): State<Arc<App>>,
    path: Result<Path<TilePath>, axum::extract::rejection::PathRejection>,
    RawQuery(query): RawQuery,
    method: Method,
    conditional: Conditional,
) -> Result<Response, Problem> {
    let Path((name, z, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let (y, f32_form) = if let Some(y) = file.strip_suffix(".png") {
        (y, false)
    } else if let Some(y) = file.strip_suffix(".f32") {
        (y, true)
    } else {
        return Err(Problem::not_found(format!("{file:?}: heightmap tiles are {{y}}.png or {{y}}.f32")));
    };
    let (z, x, y) = (parse_num(&z, "zoom")?, parse_num(&x, "column")?, parse_num(y, "row")?);
    let t = u8::try_from(z).ok().and_then(|z| Xyz::new(z, x, y)).ok_or_else(|| {
        Problem::not_found(format!("no heightmap tile {z}/{x}/{y}: zooms 0 to {MAX_ZOOM}, x and y below 2^z"))
    })?;
    let ask = Ask::parse(query.as_deref())?;
    if f32_form && query.as_deref().is_some_and(|q| q.contains("encoding=")) {
        return Err(Problem::bad_request("encoding applies to .png tiles; .f32 tiles are float32 metres"));
    }
    let ext = extent(&ts)?;
    if !ext.meets(t) {
        return Err(Problem::not_found(format!(
            "heightmap tile {z}/{x}/{y} lies outside the data of {name:?} (tiles.json gives its bounds)"
        )));
    }
    let ck = (ts.generation, TileKey::new(t.z, t.x, t.y), ask.variant(f32_form));
    let entry = if let Some(e) = app.cache.get(&ck) {
        e
    } else {
        let heights = tile_heights(&app, &ts, t, ask, &ext).await?;
        let body = if f32_form { hm::f32_tile(&heights) } else { hm::png(&heights, ask.encoding) };
        let e = Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) };
        app.cache.insert(ck, e.clone());
        e
    };
    let ctype = if f32_form { "application/octet-stream" } else { "image/png" };
    let mut r = send(&method, &conditional, &entry, ctype, versioned_cache(&ts, query.as_deref()));
    if f32_form {
        r.headers_mut().insert("x-heightmap-size", HeaderValue::from(TILE_PX));
    }
    Ok(r)
}

/// The heights of a tile's pixel centres (`None`: no data).
async fn tile_heights(
    app: &Arc<App>,
    ts: &Arc<Tileset>,
    t: Xyz,
    ask: Ask,
    ext: &Extent,
) -> Result<Vec<Option<f64>>, Problem> {
    let surface = match ask.surface {
        Surface::Source => Surface::Source,
        Surface::Mesh { .. } => {
            let m: crate::store::Manifest = serde_json::from_slice(&ts.manifest_json)
                .map_err(|_| Problem::internal("heightmap", "the manifest cannot be read"))?;
            Surface::Mesh { depth: Some(hm::mesh_depth(t, ext.cell_m, m.depth)) }
        }
    };
    let which: Arc<Sampler> = Arc::new(sampler(ts, surface)?);
    let points = Arc::new(t.pixel_centres());
    let q = Query { coords: Coords::Wgs84, interp: Interp::Bilinear, datum: ask.datum };
    let hs = chunk(app, ts, &which, &points, 0, q).await?;
    Ok(hs.into_iter().map(|h| (!h.nodata && h.h.is_finite()).then_some(h.h)).collect())
}
