//! `POST /tilesets/{name}/heights` and `GET /tilesets/{name}/heights?points=…`: the height under
//! each point, for simulators. Points come as JSON (`[[x, y], …]` or `{"points": [[x, y], …]}`),
//! as a binary body of little-endian f64 pairs (`application/octet-stream`), or in the query
//! (`points=x,y;x,y`, at most [`MAX_GET_POINTS`]). Options in the query: `coords=wgs84|crs|local`,
//! `surface=mesh|source`, `interpolation=nearest|bilinear|cubic` (source), `depth=Z` (mesh:
//! the depth of the nodes whose TIN answers; the finest by default), `datum=ellipsoid|geoid|
//! native`. Answers of more than [`CHUNK`] points stream in chunks of that many (smaller ones come
//! whole), as JSON (one object a point) or, for `Accept:
//! application/octet-stream`, 16 bytes a point (f64 height, f32 error bound, u32 flags: bit 0
//! no data). Every point is checked before the first byte is sent (a bad one is a `400` naming
//! it); limits: [`MAX_POINTS`] points, [`MAX_BODY_BYTES`] of body, the request timeout until the
//! first chunk.

use std::collections::HashMap;
use std::sync::Arc;

use axum::body::{Body, Bytes};
use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::Response;

use super::App;
use super::loaders::{load_blob, tileset};
use super::problem::Problem;
use super::registry::Tileset;
use crate::heights::{
    BlobSource, Coords, Datum, Height, HeightsError, Interp, MeshSampler, Query, SourceSampler,
};
use crate::raster::Georef;
use crate::tiling::{Pyramid, TileKey};

/// Points in one request.
pub const MAX_POINTS: usize = 1_000_000;
/// Points in a `GET` query.
pub const MAX_GET_POINTS: usize = 1_000;
/// Body bytes of one request (1,000,000 points as JSON with full-precision decimals fit).
pub const MAX_BODY_BYTES: usize = 64 << 20;
/// Points answered per chunk of the response.
pub const CHUNK: usize = 65_536;
/// Batches up to this many points are checked and answered on the request's own task.
const INLINE_POINTS: usize = 1_024;
/// Decoded TINs the server keeps for height queries (bytes), shared by requests.
pub const MESH_CACHE_BYTES: usize = 256 << 20;

/// Which surface answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Surface {
    Mesh { depth: Option<u8> },
    Source,
}

#[derive(Debug, Clone, Copy)]
struct Options {
    query: Query,
    surface: Surface,
}

fn parse_options(raw: Option<&str>) -> Result<(Options, Option<String>), Problem> {
    let mut query = Query::default();
    let mut surface = None;
    let mut interp = None;
    let mut depth = None;
    let mut points = None;
    for pair in raw.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        let v = percent_decode(v);
        let bad = |what: &str| Problem::bad_request(format!("query parameter {k}={v:?}: {what}"));
        match k {
            "coords" => {
                let choices = [("wgs84", Coords::Wgs84), ("crs", Coords::Crs), ("local", Coords::Local)];
                query.coords = one_of(&v, &choices).map_err(|w| bad(&w))?;
            }
            "datum" => {
                let choices =
                    [("ellipsoid", Datum::Ellipsoid), ("geoid", Datum::Geoid), ("native", Datum::Native)];
                query.datum = one_of(&v, &choices).map_err(|w| bad(&w))?;
            }
            "surface" => {
                surface = Some(one_of(&v, &[("mesh", false), ("source", true)]).map_err(|w| bad(&w))?);
            }
            "interpolation" => {
                let choices =
                    [("nearest", Interp::Nearest), ("bilinear", Interp::Bilinear), ("cubic", Interp::Cubic)];
                interp = Some(one_of(&v, &choices).map_err(|w| bad(&w))?);
            }
            "depth" => depth = Some(v.parse::<u8>().map_err(|_| bad("a node depth, 0 to 24"))?),
            "points" => points = Some(v),
            "v" => {}
            _ => {
                return Err(Problem::bad_request(format!(
                    "unknown query parameter {k:?}: use coords, surface, interpolation, depth, datum (and points for GET)"
                )));
            }
        }
    }
    // `interpolation` applies to the source, `depth` to the mesh; each is ignored by the other
    // surface (documented), so any combination the API document allows is answered.
    let surface = if surface == Some(true) {
        query.interp = interp.unwrap_or_default();
        Surface::Source
    } else {
        Surface::Mesh { depth }
    };
    Ok((Options { query, surface }, points))
}

/// The value `v` names among `choices`; otherwise what to use instead ("use a, b or c").
fn one_of<T: Copy>(v: &str, choices: &[(&str, T)]) -> Result<T, String> {
    if let Some(&(_, t)) = choices.iter().find(|(name, _)| *name == v) {
        return Ok(t);
    }
    let names: Vec<&str> = choices.iter().map(|(name, _)| *name).collect();
    match names.split_last() {
        Some((last, [])) => Err(format!("use {last}")),
        Some((last, rest)) => Err(format!("use {} or {last}", rest.join(", "))),
        None => Err("no value is accepted".to_owned()),
    }
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut k = 0;
    while k < b.len() {
        match b[k] {
            b'%' if k + 2 < b.len() => {
                let hex =
                    std::str::from_utf8(&b[k + 1..k + 3]).ok().and_then(|h| u8::from_str_radix(h, 16).ok());
                if let Some(v) = hex {
                    out.push(v);
                    k += 3;
                    continue;
                }
                out.push(b'%');
            }
            b'+' => out.push(b' '),
            c => out.push(c),
        }
        k += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The points of a `GET` query: `x,y;x,y;…`.
fn parse_query_points(s: &str) -> Result<Vec<[f64; 2]>, Problem> {
    let mut out = Vec::new();
    for (index, p) in s.split(';').filter(|p| !p.trim().is_empty()).enumerate() {
        if index >= MAX_GET_POINTS {
            return Err(Problem::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                "too-many-points",
                format!("a GET asks for at most {MAX_GET_POINTS} points; POST more"),
            ));
        }
        let mut it = p.split(',').map(str::trim);
        let mut num = || {
            it.next()
                .and_then(|v| v.parse::<f64>().ok())
                .ok_or_else(|| Problem::bad_request(format!("point {index}: {p:?} is not x,y")))
        };
        let xy = [num()?, num()?];
        if it.next().is_some() {
            return Err(Problem::bad_request(format!("point {index}: {p:?} has more than two coordinates")));
        }
        out.push(xy);
    }
    Ok(out)
}

/// The points of a `POST` body.
fn parse_body(headers: &HeaderMap, body: &[u8]) -> Result<Vec<[f64; 2]>, Problem> {
    let ctype = headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).unwrap_or("application/json");
    let mime = ctype.split(';').next().unwrap_or("").trim().to_ascii_lowercase();
    let points = match mime.as_str() {
        "application/octet-stream" => {
            if !body.len().is_multiple_of(16) {
                return Err(Problem::bad_request(format!(
                    "binary body of {} bytes: points are pairs of little-endian f64 (16 bytes each)",
                    body.len()
                )));
            }
            if body.len() / 16 > MAX_POINTS {
                return Err(too_many(body.len() / 16));
            }
            body.chunks_exact(16)
                .map(|c| {
                    let f = |o: usize| f64::from_le_bytes(c[o..o + 8].try_into().unwrap_or([0; 8]));
                    [f(0), f(8)]
                })
                .collect()
        }
        "application/json" | "" => {
            #[derive(serde::Deserialize)]
            #[serde(deny_unknown_fields)]
            struct Wrapped {
                points: Vec<[f64; 2]>,
            }
            let first = body.iter().find(|b| !b.is_ascii_whitespace());
            let parsed = if first == Some(&b'{') {
                serde_json::from_slice::<Wrapped>(body).map(|w| w.points)
            } else {
                serde_json::from_slice::<Vec<[f64; 2]>>(body)
            };
            parsed.map_err(|e| {
                Problem::bad_request(format!(
                    "JSON body: {e}; send [[x, y], …] or {{\"points\": [[x, y], …]}} (options go in the query)"
                ))
            })?
        }
        other => {
            return Err(Problem::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported-media-type",
                format!("Content-Type {other:?}: send application/json or application/octet-stream"),
            ));
        }
    };
    if points.len() > MAX_POINTS {
        return Err(too_many(points.len()));
    }
    Ok(points)
}

fn too_many(n: usize) -> Problem {
    Problem::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        "too-many-points",
        format!("{n} points: a request asks for at most {MAX_POINTS}; split the batch"),
    )
}

pub(super) async fn get(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    RawQuery(raw): RawQuery,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let (opts, points) = parse_options(raw.as_deref())?;
    let points = parse_query_points(
        &points.ok_or_else(|| Problem::bad_request("GET needs points=x,y;x,y (or POST a body)"))?,
    )?;
    answer(app, ts, opts, points, &headers).await
}

pub(super) async fn post(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    RawQuery(raw): RawQuery,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let (opts, in_query) = parse_options(raw.as_deref())?;
    if in_query.is_some() {
        return Err(Problem::bad_request("POST sends its points in the body, not in the query"));
    }
    let bytes = axum::body::to_bytes(body, MAX_BODY_BYTES).await.map_err(|_| {
        Problem::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too-large",
            format!("the body is larger than {MAX_BODY_BYTES} bytes; split the batch"),
        )
    })?;
    let points = parse_body(&headers, &bytes)?;
    answer(app, ts, opts, points, &headers).await
}

/// Blobs fetched ahead for a chunk (the sampler runs on a blocking thread).
struct Fetched(HashMap<TileKey, Bytes>);

impl BlobSource for Fetched {
    fn blob(&self, key: TileKey) -> Result<Option<Vec<u8>>, String> {
        Ok(self.0.get(&key).map(|b| b.to_vec()))
    }
}

fn heights_problem(e: &HeightsError) -> Problem {
    match e {
        HeightsError::NonFinite { .. }
        | HeightsError::Latitude { .. }
        | HeightsError::Longitude { .. }
        | HeightsError::Transform { .. } => Problem::bad_request(e.to_string()),
        HeightsError::Depth { .. } => Problem::not_found(e.to_string()),
        // The tileset, not the request, lacks what the options need.
        HeightsError::NotPlaced { .. } => Problem::new(StatusCode::CONFLICT, "not-placed", e.to_string()),
        _ => Problem::internal("heights", e.to_string()),
    }
}

/// What answers: the dataset (`surface=source`) or the tileset's TINs.
pub(super) enum Sampler {
    Source(Arc<super::registry::Source>),
    Mesh { pyramid: Pyramid, georef: Box<Georef>, depth: u8 },
}

pub(super) fn sampler(ts: &Tileset, surface: Surface) -> Result<Sampler, Problem> {
    match surface {
        Surface::Source => ts.source.clone().map(Sampler::Source).ok_or_else(|| {
            Problem::new(
                StatusCode::CONFLICT,
                "no-source",
                format!(
                    "tileset {:?} is served from its store without its source raster: surface=source needs \
                     `serve --source {}=RASTER`; surface=mesh answers from the stored TINs",
                    ts.name, ts.name
                ),
            )
        }),
        Surface::Mesh { depth } => {
            let not_terrain = || {
                Problem::new(
                    StatusCode::CONFLICT,
                    "not-terrain",
                    format!("tileset {:?} is not a terrain tileset: heights apply to terrain", ts.name),
                )
            };
            // A model's manifest carries every terrain field too: its `kind` tells them apart.
            let kind: serde_json::Value =
                serde_json::from_slice(&ts.manifest_json).map_err(|_| not_terrain())?;
            if kind.get("kind").and_then(serde_json::Value::as_str).is_some_and(|k| k != "terrain") {
                return Err(not_terrain());
            }
            let m: crate::store::Manifest =
                serde_json::from_slice(&ts.manifest_json).map_err(|_| not_terrain())?;
            let pyramid = Pyramid::new(m.source.width, m.source.height, m.tile_size)
                .map_err(|e| Problem::internal("heights", format!("tileset {:?}: {e}", ts.name)))?;
            let depth = depth.unwrap_or(pyramid.depth);
            if depth > pyramid.depth {
                // Like a tile the tileset does not have.
                return Err(Problem::not_found(format!(
                    "depth {depth}: the finest nodes of {:?} are at depth {}",
                    ts.name, pyramid.depth
                )));
            }
            Ok(Sampler::Mesh { pyramid, georef: Box::new(m.frame), depth })
        }
    }
}

async fn answer(
    app: Arc<App>,
    ts: Arc<Tileset>,
    opts: Options,
    points: Vec<[f64; 2]>,
    headers: &HeaderMap,
) -> Result<Response, Problem> {
    let binary = headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|a| a.contains("application/octet-stream") && !a.contains("application/json"));
    let which = Arc::new(sampler(&ts, opts.surface)?);
    let points = Arc::new(points);
    // Every point is checked (and the first chunk answered) before the response starts, so a
    // bad point is a 400, not a torn body.
    if points.len() <= INLINE_POINTS {
        check_all(&points, opts.query).map_err(|e| heights_problem(&e))?;
    } else {
        let points = points.clone();
        tokio::task::spawn_blocking(move || check_all(&points, opts.query))
            .await
            .map_err(|_| Problem::internal("heights", "checking the points failed"))?
            .map_err(|e| heights_problem(&e))?;
    }
    let first = chunk(&app, &ts, &which, &points, 0, opts.query).await?;
    let n = points.len();
    let head = if binary { Bytes::new() } else { Bytes::from(json_head(&ts.name, opts, n)) };
    if first.len() == n {
        // One chunk: the whole answer at once, with its length.
        let mut body = head.to_vec();
        if binary {
            body.extend_from_slice(&binary_chunk(&first));
        } else {
            body.extend_from_slice(&json_chunk(&first, true));
            body.extend_from_slice(b"]}");
        }
        return Ok(heights_response(Body::from(body), binary, n));
    }
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<Bytes, std::io::Error>>(2);
    let encode = move |hs: &[Height], first_chunk: bool| -> Bytes {
        if binary { Bytes::from(binary_chunk(hs)) } else { Bytes::from(json_chunk(hs, first_chunk)) }
    };
    tokio::spawn(async move {
        let send = |b: Bytes| {
            let tx = tx.clone();
            async move { tx.send(Ok(b)).await.is_ok() }
        };
        if !head.is_empty() && !send(head).await {
            return;
        }
        if !send(encode(&first, true)).await {
            return;
        }
        let mut start = first.len();
        while start < n {
            match chunk(&app, &ts, &which, &points, start, opts.query).await {
                Ok(hs) => {
                    start += hs.len();
                    if !send(encode(&hs, false)).await {
                        return;
                    }
                }
                Err(p) => {
                    // The status is sent: the body is cut short, which the client sees as an
                    // incomplete response (no closing bracket, fewer bytes than 16 per point).
                    tracing::error!(tileset = %ts.name, detail = %p.detail, "heights: a chunk failed mid-response");
                    let _ = tx.send(Err(std::io::Error::other(p.detail))).await;
                    return;
                }
            }
        }
        if !binary {
            let _ = send(Bytes::from_static(b"]}")).await;
        }
    });
    let mut rx = rx;
    let stream = futures_util::stream::poll_fn(move |cx| rx.poll_recv(cx));
    let mut r = heights_response(Body::from_stream(stream), binary, n);
    if binary {
        r.headers_mut().insert(header::CONTENT_LENGTH, HeaderValue::from(n * 16));
    }
    Ok(r)
}

/// A heights answer of `n` points: binary or JSON, never cached, with `X-Points`.
fn heights_response(body: Body, binary: bool, n: usize) -> Response {
    let mut r = Response::new(body);
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(if binary { "application/octet-stream" } else { "application/json" }),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert("x-points", HeaderValue::from(n));
    r
}

fn check_all(points: &[[f64; 2]], q: Query) -> Result<(), HeightsError> {
    for (index, p) in points.iter().enumerate() {
        crate::heights::check(index, *p, q.coords)?;
    }
    Ok(())
}

/// The answers for `points[start..start + CHUNK]`.
pub(super) async fn chunk(
    app: &Arc<App>,
    ts: &Arc<Tileset>,
    which: &Arc<Sampler>,
    points: &Arc<Vec<[f64; 2]>>,
    start: usize,
    q: Query,
) -> Result<Vec<Height>, Problem> {
    let end = (start + CHUNK).min(points.len());
    let fetched = match which.as_ref() {
        Sampler::Source(_) => HashMap::new(),
        Sampler::Mesh { pyramid, georef, depth } => {
            let keys = {
                let (pyramid, georef, depth) = (*pyramid, georef.as_ref().clone(), *depth);
                let points = points.clone();
                tokio::task::spawn_blocking(move || {
                    crate::heights::mesh::nodes_of(&points[start..end], q.coords, pyramid, &georef, depth)
                })
                .await
                .map_err(|_| Problem::internal("heights", "locating the points failed"))?
                .map_err(|e| heights_problem(&e))?
            };
            let mut fetched = HashMap::with_capacity(keys.len());
            for key in keys.into_iter().filter(|&k| !app.meshes.contains(ts.generation, k)) {
                match load_blob(app, ts, key, 0).await {
                    Ok(e) => {
                        fetched.insert(key, e.bytes);
                    }
                    Err(p) if p.status == StatusCode::NOT_FOUND => {}
                    Err(p) => return Err(p),
                }
            }
            fetched
        }
    };
    let (which, points) = (which.clone(), points.clone());
    let (cache, tag) = (app.meshes.clone(), ts.generation);
    // A small batch with nothing to decode is answered here (microseconds); larger ones and
    // ones that decode TINs on a blocking thread.
    let inline = end - start <= INLINE_POINTS && fetched.is_empty();
    let work = move || -> Result<Vec<Height>, HeightsError> {
        let pts = &points[start..end];
        match which.as_ref() {
            Sampler::Source(src) => {
                SourceSampler::new(&src.raster.heights, &src.raster.georef)?.sample_from(pts, q, start)
            }
            Sampler::Mesh { pyramid, georef, depth } => {
                MeshSampler::with_cache(Fetched(fetched), *pyramid, georef, cache, tag)?
                    .sample_from(pts, q, *depth, start)
            }
        }
    };
    let answered = if inline {
        work()
    } else {
        tokio::task::spawn_blocking(work)
            .await
            .map_err(|_| Problem::internal("heights", "answering the points failed"))?
    };
    answered.map_err(|e| heights_problem(&e))
}

fn json_head(name: &str, opts: Options, n: usize) -> String {
    let (surface, extra) = match opts.surface {
        Surface::Source => ("source", format!(",\"interpolation\":{:?}", interp_name(opts.query.interp))),
        Surface::Mesh { depth } => ("mesh", depth.map(|d| format!(",\"depth\":{d}")).unwrap_or_default()),
    };
    format!(
        "{{\"tileset\":{},\"surface\":\"{surface}\"{extra},\"coords\":\"{}\",\"datum\":\"{}\",\"count\":{n},\"heights\":[",
        serde_json::Value::from(name),
        opts.query.coords.name(),
        opts.query.datum.name()
    )
}

fn interp_name(i: Interp) -> &'static str {
    match i {
        Interp::Nearest => "nearest",
        Interp::Bilinear => "bilinear",
        Interp::Cubic => "cubic",
    }
}

/// One chunk of the JSON answer: `{"h":…,"error":…,"nodata":…}` per point (`null` height and
/// error where there is no data).
fn json_chunk(hs: &[Height], first: bool) -> Vec<u8> {
    use std::io::Write;
    let mut out = Vec::with_capacity(hs.len() * 48);
    for (k, h) in hs.iter().enumerate() {
        if k > 0 || !first {
            out.push(b',');
        }
        if h.nodata || !h.h.is_finite() {
            out.extend_from_slice(b"{\"h\":null,\"error\":null,\"nodata\":true}");
        } else {
            let e = if h.error.is_finite() { h.error.to_string() } else { "null".into() };
            let _ = write!(out, "{{\"h\":{},\"error\":{e},\"nodata\":false}}", h.h);
        }
    }
    out
}

/// One chunk of the binary answer: per point f64 height, f32 error, u32 flags (bit 0: no data),
/// little-endian; NaN height and error where there is no data.
fn binary_chunk(hs: &[Height]) -> Vec<u8> {
    let mut out = Vec::with_capacity(hs.len() * 16);
    for h in hs {
        out.extend_from_slice(&h.h.to_le_bytes());
        out.extend_from_slice(&(h.error as f32).to_le_bytes());
        out.extend_from_slice(&u32::from(h.nodata).to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn named_options_parse_and_bad_ones_say_what_to_use() {
        let (o, points) =
            parse_options(Some("coords=crs&datum=geoid&surface=source&interpolation=cubic&points=1,2"))
                .unwrap();
        assert_eq!(
            (o.query.coords, o.query.datum, o.query.interp),
            (Coords::Crs, Datum::Geoid, Interp::Cubic)
        );
        assert_eq!((o.surface, points.as_deref()), (Surface::Source, Some("1,2")));
        let (o, _) = parse_options(Some("surface=mesh&depth=3")).unwrap();
        assert_eq!(o.surface, Surface::Mesh { depth: Some(3) });
        for (q, says) in [
            ("coords=x", r#"query parameter coords="x": use wgs84, crs or local"#),
            ("datum=", r#"query parameter datum="": use ellipsoid, geoid or native"#),
            ("surface=MESH", r#"query parameter surface="MESH": use mesh or source"#),
            (
                "interpolation=linear",
                r#"query parameter interpolation="linear": use nearest, bilinear or cubic"#,
            ),
        ] {
            let e = parse_options(Some(q)).unwrap_err();
            assert_eq!((e.status, e.detail.as_str()), (axum::http::StatusCode::BAD_REQUEST, says), "{q}");
        }
        assert_eq!(one_of("b", &[("a", 1), ("b", 2)]), Ok(2));
        assert_eq!(one_of("c", &[("a", 1)]), Err("use a".to_owned()));
        assert_eq!(one_of::<u8>("c", &[]), Err("no value is accepted".to_owned()));
    }
}
