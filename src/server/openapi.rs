//! The OpenAPI 3.1 document served at `/openapi.json`, written by hand to match the routes
//! (`tests/server.rs` requests every operation it lists and checks that the router has it).

use serde_json::{Map, Value, json};

fn problem(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}}})
}

/// A problem answer that asks the client to wait (`Retry-After`, seconds).
fn retry_problem(desc: &str) -> Value {
    let mut p = problem(desc);
    if let Some(o) = p.as_object_mut() {
        o.insert(
            "headers".into(),
            json!({"Retry-After": {"description": "seconds to wait before retrying", "schema": {"type": "integer", "minimum": 1}}}),
        );
    }
    p
}

fn name_param() -> Value {
    json!({"name": "name", "in": "path", "required": true, "schema": {"type": "string", "pattern": "^[a-z0-9_-]{1,64}$"}})
}

fn int_param(n: &str) -> Value {
    json!({"name": n, "in": "path", "required": true, "schema": {"type": "integer", "minimum": 0, "maximum": u32::MAX}})
}

/// A success answer with no body (204).
fn empty(desc: &str) -> Value {
    json!({"description": desc})
}

/// A success answer whose body is a bake job (`application/json`).
fn job(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Job"}}}})
}

fn v_param() -> Value {
    json!({"name": "v", "in": "query", "required": false, "schema": {"type": "string"},
        "description": "The tileset's content_version, as the server's own URIs carry it (on the 3D Tiles routes under /3dtiles/ followed by the GLB revision, e.g. `.g4`). When it matches, the response is `Cache-Control: public, max-age=31536000, immutable`; otherwise it is revalidated after 60 s."})
}

/// `glb=` of the 3D Tiles routes (`server::tiles3d`): how the GLBs are compressed, carried into
/// every URI a tileset JSON lists.
fn glb_param() -> Value {
    use crate::formats::tiles3d::GlbCompression;
    let (none, meshopt, draco) =
        (GlbCompression::None.name(), GlbCompression::Meshopt.name(), GlbCompression::Draco.name());
    let all: Vec<&str> = GlbCompression::ALL.iter().map(|c| c.name()).collect();
    json!({"name": "glb", "in": "query", "required": false,
        "schema": {"type": "string", "enum": all, "default": none},
        "description": format!("`{meshopt}`: GLBs with EXT_meshopt_compression; `{draco}`: mesh GLBs with KHR_draco_mesh_compression and point GLBs with EXT_meshopt_compression (the reader must support the extension); a tileset JSON whose every URI carries the option; each form is cached apart. `{none}` or absent: plain glTF. Any other value: 400.")})
}

/// `params` (a JSON array) with [`glb_param`] added.
fn with_glb(mut params: Value) -> Value {
    if let Some(a) = params.as_array_mut() {
        a.push(glb_param());
    }
    params
}

/// The 400 of a 3D Tiles route, which also refuses a bad `glb=`.
const GLB_400: (&str, &str) = (
    "400",
    "Malformed name, key or level (not a non-negative integer of at most 2^32 − 1), or a glb= other than none, meshopt or draco",
);

/// The error answers every read route can give, plus `extra`.
fn errors(extra: &[(&str, &str)]) -> Map<String, Value> {
    let mut m = Map::new();
    m.insert(
        "400".into(),
        problem("Malformed name, key or level (not a non-negative integer of at most 2^32 − 1)"),
    );
    m.insert("401".into(), problem("No bearer token (only when the server runs with --read-token)"));
    m.insert("403".into(), problem("Wrong bearer token (only when the server runs with --read-token)"));
    m.insert("404".into(), problem("Unknown tileset, or a z/x/y/level the tileset does not have"));
    m.insert("429".into(), retry_problem("Rate limited (--rate-limit)"));
    m.insert(
        "503".into(),
        retry_problem("Overloaded, bake queue full, timed out, not ready, or the store cannot be read"),
    );
    for (k, v) in extra {
        m.insert((*k).into(), problem(v));
    }
    m
}

/// `GET` and `HEAD` of a cacheable document: 200 with `ETag`/`Cache-Control`, 304, ranges.
fn cached_get(
    summary: &str,
    params: &Value,
    ok_desc: &str,
    ctype: &str,
    schema: &Value,
    extra: &[(&str, &str)],
) -> Value {
    let mut responses = errors(&[("416", "Range not satisfiable (Content-Range: bytes */LEN)")]);
    for (k, v) in extra {
        responses.insert((*k).into(), problem(v));
    }
    let headers = json!({
        "ETag": {"description": "strong entity tag of the content", "schema": {"type": "string"}},
        "Cache-Control": {"schema": {"type": "string"}},
        "Content-Length": {"schema": {"type": "integer"}},
        "Accept-Ranges": {"schema": {"const": "bytes"}}});
    let mut get_resp = responses.clone();
    get_resp.insert(
        "200".into(),
        json!({"description": ok_desc, "headers": headers, "content": {ctype: {"schema": schema}}}),
    );
    get_resp.insert("206".into(), json!({"description": "One byte range (Range: bytes=a-b, a-, -n)", "headers": {"Content-Range": {"schema": {"type": "string"}}}}));
    get_resp.insert("304".into(), json!({"description": "Not modified (If-None-Match matches the ETag)"}));
    let mut head_resp = responses;
    head_resp
        .insert("200".into(), json!({"description": format!("{ok_desc}: headers only"), "headers": headers}));
    head_resp.insert("304".into(), json!({"description": "Not modified (If-None-Match matches the ETag)"}));
    json!({
        "parameters": params,
        "get": {"summary": summary, "security": [{}, {"read": []}], "responses": get_resp},
        "head": {"summary": format!("{summary} (headers only)"), "security": [{}, {"read": []}], "responses": head_resp},
    })
}

#[must_use]
pub fn document() -> Value {
    let key_params = |level: bool| {
        let mut p = vec![name_param(), int_param("z"), int_param("x"), int_param("y")];
        if level {
            p.push(int_param("level"));
        }
        p.push(v_param());
        Value::Array(p)
    };
    // Problems of the admin routes, plus their success answers `ok`.
    let admin = |extra: &[(&str, &str)], ok: &[(&str, Value)]| {
        let mut m = Map::new();
        m.insert("401".into(), problem("No bearer token"));
        m.insert("403".into(), problem("Wrong token, or the admin API is off (no --admin-token)"));
        for (k, v) in extra {
            m.insert((*k).into(), problem(v));
        }
        for (k, v) in ok {
            m.insert((*k).into(), v.clone());
        }
        Value::Object(m)
    };
    let mut started = job("Job started; body: the job (its progress is at Location: /jobs/{id})");
    if let Some(o) = started.as_object_mut() {
        o.insert("headers".into(), json!({"Location": {"schema": {"type": "string"}}}));
        o.insert(
            "links".into(),
            json!({"job": {"operationId": "getJob", "parameters": {"id": "$response.body#/id"}}}),
        );
    }
    let any = json!({});
    json!({
        "openapi": "3.1.0",
        "info": {"title": "terrastream", "version": env!("CARGO_PKG_VERSION"),
            "description": "Tiled terrain LOD (TIN mesh + point-cloud levels) over HTTP. Every error is application/problem+json; a method a route does not have is 405 with Allow; every response allows any origin (CORS)."},
        "paths": {
            "/healthz": {"get": {"summary": "Alive", "responses": {"200": {"description": "alive"}}}},
            "/readyz": {"get": {"summary": "Store readable and tilesets loaded", "responses": {"200": {"description": "ready"}, "503": retry_problem("not ready")}}},
            "/metrics": {"get": {"summary": "Prometheus metrics", "responses": {"200": {"description": "Prometheus text format", "content": {"text/plain; version=0.0.4": {}}}}}},
            "/openapi.json": {"get": {"summary": "This document", "responses": {"200": {"description": "OpenAPI 3.1", "content": {"application/json": {}}}}}},
            "/tilesets": cached_get("Tilesets served, with manifest summaries", &json!([]), "list", "application/json",
                &json!({"type": "object", "properties": {"tilesets": {"type": "array", "items": {"$ref": "#/components/schemas/Summary"}}}}), &[]),
            "/tilesets/{name}": {
                "parameters": [name_param()],
                "get": {"summary": "One tileset's summary", "security": [{}, {"read": []}],
                    "responses": Value::Object({
                        let mut m = errors(&[]);
                        m.insert("200".into(), json!({"description": "summary", "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Summary"}}}}));
                        m
                    })},
                "post": {"summary": "Admin: upload a raster and bake it as a new tileset",
                    "security": [{"admin": []}],
                    "parameters": [
                        {"name": "encoding", "in": "query", "schema": {"enum": ["gray16", "terrain-rgb", "terrarium"]}},
                        {"name": "cell_size", "in": "query", "schema": {"type": "number", "minimum": crate::raster::MIN_CELL_SIZE, "maximum": crate::raster::MAX_CELL_SIZE}},
                        {"name": "tile_size", "in": "query", "schema": {"type": "integer", "minimum": 2, "maximum": 65_536}},
                        {"name": "max_error", "in": "query", "schema": {"type": "number", "minimum": 0, "maximum": f64::MAX}},
                        {"name": "levels", "in": "query", "schema": {"type": "integer", "minimum": 0, "maximum": crate::bake::MAX_LEVELS}}],
                    "requestBody": {"content": {"application/octet-stream": {}}},
                    "description": "The upload is stored, then baked by a job: a file that is not a raster, or a raster beyond the limits, makes the job fail (GET /jobs/{id} says why), not the upload.",
                    "responses": admin(&[("400", "Options outside their ranges, or unknown query keys"), ("409", "Tileset exists"), ("413", "Upload larger than --max-body-bytes"), ("500", "The upload could not be stored")], &[("202", started)])},
                "delete": {"summary": "Admin: delete a tileset", "security": [{"admin": []}],
                    "responses": admin(&[("400", "Bad name"), ("404", "No such tileset"), ("409", "On-demand tileset")], &[("204", empty("Deleted"))])}
            },
            "/tilesets/{name}/tileset.json": cached_get("Manifest", &json!([name_param()]), "manifest", "application/json", &any, &[]),
            "/tilesets/{name}/index/{z}/{x}/{y}.json": cached_get("Index chunk rooted at a z multiple of 4",
                &key_params(false), "index chunk", "application/json", &any, &[]),
            "/tilesets/{name}/tiles/{z}/{x}/{y}/{level}": cached_get("One blob (baked on first request for --source tilesets; {level}.tsb is accepted too)",
                &key_params(true), "blob", "application/vnd.terrastream.blob", &json!({"type": "string", "format": "binary"}),
                &[("500", "Stored blob failed its checksum (never sent) or the bake failed")]),
            "/tilesets/{name}/3dtiles/tileset.json": cached_get("OGC 3D Tiles 1.1 root tileset, made from the stored index (the root transform places it at the anchor; asset.extras.terrastream says where and why)",
                &with_glb(json!([name_param()])), "3D Tiles tileset", "application/json", &any,
                &[GLB_400, ("500", "The manifest, index or placement cannot be read")]),
            "/tilesets/{name}/3dtiles/index/{z}/{x}/{y}.json": cached_get("3D Tiles external tileset of the index chunk rooted at z/x/y (z a multiple of 4, not 0)",
                &with_glb(key_params(false)), "3D Tiles tileset", "application/json", &any,
                &[GLB_400, ("500", "The manifest or index cannot be read")]),
            "/tilesets/{name}/3dtiles/tiles/{z}/{x}/{y}/{level}.glb": cached_get("One (tile, level) as glTF 2.0 binary (made from its verified blob; baked on first request for --source tilesets)",
                &with_glb(key_params(true)), "GLB", crate::formats::tiles3d::GLB_TYPE, &json!({"type": "string", "format": "binary"}),
                &[GLB_400, ("500", "Stored blob failed its checksum (never sent), the bake failed, or the GLB could not be compressed")]),
            "/tilesets/{name}/terrain/layer.json": cached_get("Cesium quantized-mesh-1.0 globe terrain: layer.json (TileJSON; available tiles per zoom, metadataAvailability, extensions). From a tileset baked with --terrain, or made from its --source",
                &json!([name_param()]), "layer document", "application/json", &any,
                &[("500", "The stored layer cannot be read, or the source cannot be placed on the Earth")]),
            "/tilesets/{name}/terrain/{z}/{x}/{y}.terrain": cached_get("One quantized-mesh-1.0 tile of the global geodetic TMS grid (2 root tiles). Accept: application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata picks the extensions sent (Vary: accept, accept-encoding); gzip when Accept-Encoding allows. Stored, or built on first request for --source tilesets",
                &key_params(false), "quantized-mesh tile", crate::formats::qmesh::QM_TYPE, &json!({"type": "string", "format": "binary"}),
                &[("406", "Accept names neither quantized-mesh nor a wildcard"), ("500", "A stored tile cannot be read or decoded, or the build failed")]),
            "/tilesets/{name}/heights": heights_ops(),
            "/tilesets/{name}/heightmap/tiles.json": cached_get("TileJSON 3.0 of the heightmap tiles (bounds, zooms, encoding, tile URL template): a MapLibre GL raster-dem source `url`",
                &heightmap_params(false, true), "TileJSON", "application/json", &any,
                &[("409", "The tileset is not placed on the Earth (no CRS)")]),
            "/tilesets/{name}/heightmap/{z}/{x}/{y}.png": cached_get("One heightmap tile of the Web-Mercator XYZ grid, 256×256 PNG in the Terrarium or Mapbox Terrain-RGB encoding (no data: 0 m); made on request from the TIN at the tile's scale or the source, and cached (docs/heights.md)",
                &heightmap_params(true, true), "PNG", "image/png", &json!({"type": "string", "format": "binary"}),
                &[("409", "The tileset is not placed on the Earth, or surface=source without a source"), ("500", "A blob the tile needs failed verification, or its bake failed")]),
            "/tilesets/{name}/heightmap/{z}/{x}/{y}.f32": cached_get("One heightmap tile as float32: 256×256 little-endian f32 metres, rows from the north, NaN where there is no data",
                &heightmap_params(true, false), "float32 heights", "application/octet-stream", &json!({"type": "string", "format": "binary"}),
                &[("409", "The tileset is not placed on the Earth, or surface=source without a source"), ("500", "A blob the tile needs failed verification, or its bake failed")]),
            "/tilesets/{name}/terrain/3dtiles/tileset.json": cached_get("The globe terrain as 3D Tiles 1.1 for CesiumJS's Cesium3DTilesTerrainProvider: a root over the globe whose two children are the hemispheres' implicit quadtrees (QUADTREE, region volumes, subtrees of 2 levels; tile metadata TILE_MINIMUM_HEIGHT, TILE_MAXIMUM_HEIGHT, TILE_BOUNDING_SPHERE, TILE_HORIZON_OCCLUSION_POINT). Same availability and content version as layer.json",
                &json!([name_param()]), "3D Tiles tileset", "application/json", &any,
                &[("500", "The stored layer cannot be read, or the source cannot be placed on the Earth")]),
            "/tilesets/{name}/terrain/3dtiles/subtrees/{root}/{level}/{x}/{y}.subtree": cached_get("One implicit-tiling subtree (binary, 2 levels) of hemisphere root (0 west, 1 east): tile, content and child-subtree availability and each tile's metadata, made from its quantized-mesh tiles (read, or built on demand, first). Level a multiple of 2; gzip when Accept-Encoding allows",
                &json!([name_param(), int_param("root"), int_param("level"), int_param("x"), int_param("y"), v_param()]), "subtree", "application/octet-stream", &json!({"type": "string", "format": "binary"}),
                &[("500", "A tile of the subtree cannot be read or decoded, or its build failed")]),
            "/tilesets/{name}/terrain/3dtiles/tiles/{root}/{level}/{x}/{y}.glb": cached_get("One terrain tile as glTF 2.0 binary: the quantized-mesh tile z = level, x = root·2^level + x, y (y from the south) with its vertices, triangles, normals and CESIUM_tile_edges edge lists for skirts; gzip when Accept-Encoding allows",
                &json!([name_param(), int_param("root"), int_param("level"), int_param("x"), int_param("y"), v_param()]), "GLB", crate::formats::tiles3d::GLB_TYPE, &json!({"type": "string", "format": "binary"}),
                &[("500", "The stored tile cannot be read or decoded, or the build failed")]),
            "/viewer": cached_get("The viewer page: any tileset of the store in 3D (?tileset=NAME picks one)", &json!([]), "HTML page", "text/html; charset=utf-8",
                &json!({"type": "string"}), &[]),
            "/jobs/{id}": {
                "parameters": [{"name": "id", "in": "path", "required": true, "schema": {"type": "string"}}],
                "get": {"summary": "Admin: bake job progress (state queued, running, done, failed or cancelled; ended jobs are forgotten after --job-ttl)",
                    "operationId": "getJob", "security": [{"admin": []}],
                    "responses": admin(&[("404", "No such job (or ended longer than --job-ttl ago)")], &[("200", job("Job state"))])},
                "delete": {"summary": "Admin: cancel a bake job (the job stays readable, state cancelled, until --job-ttl)", "security": [{"admin": []}],
                    "responses": admin(&[("404", "No such job"), ("409", "The job has already ended (done or failed)")],
                        &[("202", job("Running: it stops at its next node, then its state is cancelled; body: the job")),
                          ("204", empty("Queued (now cancelled) or already cancelled"))])}}
        },
        "components": {
            "securitySchemes": {
                "admin": {"type": "http", "scheme": "bearer", "description": "--admin-token"},
                "read": {"type": "http", "scheme": "bearer", "description": "--read-token; reading is public when it is not set"}},
            "schemas": {
                "Job": {"type": "object", "required": ["id", "tileset", "state"], "properties": {
                    "id": {"type": "string"}, "tileset": {"type": "string"},
                    "state": {"enum": ["queued", "running", "done", "failed", "cancelled"]},
                    "nodes_total": {"type": "integer"}, "nodes_done": {"type": "integer"},
                    "cancel_requested": {"type": "boolean"},
                    "error": {"type": ["string", "null"]}}},
                "Problem": {"type": "object", "properties": {
                    "type": {"type": "string"}, "title": {"type": "string"}, "status": {"type": "integer"}, "detail": {"type": "string"}}},
                "Summary": {"type": "object", "properties": {
                    "name": {"type": "string"}, "complete": {"type": "boolean"}, "content_version": {"type": "string"},
                    "source": {}, "tile_size": {"type": "integer"}, "depth": {"type": "integer"}, "levels": {"type": "integer"},
                    "bounds": {}, "totals": {}, "manifest": {"type": "string", "description": "manifest URL with ?v="},
                    "frame": {"type": "object", "description": "the world frame: x = x0 + col·dx, y = y0 + row·dy; crs (the grid in its CRS: definition, proj4, e0, n0, de, dn) or null for a local frame; vertical datum (docs/frames.md)"},
                    "globe": {"type": ["object", "null"], "description": "where the data lies on the Earth: centre {lon, lat, height} (WGS 84, ellipsoidal), crs, vertical_datum, geoid, region [west, south, east, north (degrees), min height, max height]; null for a local frame"}}}}
        }
    })
}

/// `GET` and `POST /tilesets/{name}/heights`.
fn heights_ops() -> Value {
    use crate::server::heights::{MAX_BODY_BYTES, MAX_GET_POINTS, MAX_POINTS};
    let options = json!([
        name_param(),
        {"name": "coords", "in": "query", "schema": {"enum": ["wgs84", "crs", "local"], "default": "wgs84"},
            "description": "what the points are in: WGS 84 lon, lat (degrees; 0…360 longitudes wrap), the dataset's CRS, or the tileset's world frame"},
        {"name": "surface", "in": "query", "schema": {"enum": ["mesh", "source"], "default": "mesh"},
            "description": "mesh: the TIN of the nodes at `depth` (what a client draws); source: the source raster (--source tilesets only)"},
        {"name": "interpolation", "in": "query", "schema": {"enum": ["nearest", "bilinear", "cubic"], "default": "bilinear"},
            "description": "surface=source only (ignored by surface=mesh)"},
        {"name": "depth", "in": "query", "schema": {"type": "integer", "minimum": 0, "maximum": 24},
            "description": "surface=mesh only (ignored by surface=source): the depth of the nodes whose TIN answers (default: the finest)"},
        {"name": "datum", "in": "query", "schema": {"enum": ["ellipsoid", "geoid", "native"], "default": "ellipsoid"},
            "description": "heights above the WGS 84 ellipsoid, the EGM96 geoid, or as stored; a tileset without a CRS answers coords=local, datum=native only"}
    ]);
    let answer = json!({"type": "object", "required": ["tileset", "surface", "coords", "datum", "count", "heights"], "properties": {
        "tileset": {"type": "string"}, "surface": {"enum": ["mesh", "source"]}, "coords": {"type": "string"},
        "datum": {"type": "string"}, "interpolation": {"type": "string"}, "depth": {"type": "integer"},
        "count": {"type": "integer", "minimum": 0},
        "heights": {"type": "array", "items": {"type": "object", "required": ["h", "error", "nodata"], "properties": {
            "h": {"type": ["number", "null"], "description": "metres on `datum`; null without data"},
            "error": {"type": ["number", "null"], "description": "the bound that applies: the TIN's measured maximum error, or the interpolation's (docs/heights.md)"},
            "nodata": {"type": "boolean"}}}}}});
    let ok = json!({"description": "One answer per point, in order; streamed",
        "content": {"application/json": {"schema": answer},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"},
                "description": "with Accept: application/octet-stream: 16 bytes a point, little-endian f64 height, f32 error, u32 flags (bit 0: no data)"}}});
    let responses = |extra: &[(&str, &str)]| {
        let mut m = errors(extra);
        m.insert("400".into(), problem("A bad point (named by index: not finite, latitude beyond ±90, longitude beyond −180…360), a malformed body or query, or options that do not apply"));
        m.insert(
            "409".into(),
            problem(
                "surface=source on a tileset served without its source, a tileset that is not terrain, or coords/datum that need a CRS on a tileset without one",
            ),
        );
        m.insert("200".into(), ok.clone());
        Value::Object(m)
    };
    let mut get_params = options.as_array().cloned().unwrap_or_default();
    get_params.push(json!({"name": "points", "in": "query", "required": true, "schema": {"type": "string", "pattern": "^[-+0-9.eE,;]*$"},
        "description": format!("x,y;x,y;… (at most {MAX_GET_POINTS} points)")}));
    let pair = json!({"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2});
    json!({
        "get": {"summary": "Heights at a few points (docs/heights.md)", "security": [{}, {"read": []}],
            "parameters": get_params,
            "responses": responses(&[("413", "More points than a GET takes")])},
        "post": {"summary": "Heights at a batch of points (docs/heights.md)", "security": [{}, {"read": []}],
            "parameters": options,
            "requestBody": {"required": true, "content": {
                "application/json": {"schema": {"oneOf": [
                    {"type": "array", "items": pair, "maxItems": MAX_POINTS},
                    {"type": "object", "required": ["points"], "additionalProperties": false,
                        "properties": {"points": {"type": "array", "items": pair, "maxItems": MAX_POINTS}}}]}},
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"},
                    "description": format!("finite little-endian f64 x, y pairs (16 bytes a point); at most {MAX_POINTS} points, {MAX_BODY_BYTES} bytes")}}},
            "responses": responses(&[("413", "More points or body bytes than a request takes"), ("415", "A body neither JSON nor application/octet-stream")])}
    })
}

/// The parameters of the heightmap routes (`tile`: with z/x/y and the content version).
fn heightmap_params(tile: bool, png: bool) -> Value {
    let mut p = vec![name_param()];
    if tile {
        p.extend([int_param("z"), int_param("x"), int_param("y")]);
    }
    if png {
        p.push(json!({"name": "encoding", "in": "query", "schema": {"enum": ["terrarium", "terrain-rgb", "mapbox"], "default": "terrarium"}}));
    }
    p.extend([

        json!({"name": "surface", "in": "query", "schema": {"enum": ["mesh", "source"], "default": "mesh"}}),
        json!({"name": "datum", "in": "query", "schema": {"enum": ["geoid", "ellipsoid", "native"], "default": "geoid"}}),
    ]);
    if tile {
        p.push(v_param());
    }
    Value::Array(p)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::panic)]

    use crate::formats::tiles3d::GlbCompression;

    /// Every 3D Tiles content route of the tileset (not the globe terrain's) documents `glb=`
    /// with exactly the values the server takes; no other route does.
    #[test]
    fn glb_is_documented_on_the_3d_tiles_routes_only() {
        let doc = super::document();
        let mut with = Vec::new();
        for (path, item) in doc["paths"].as_object().unwrap() {
            let glb = item["parameters"]
                .as_array()
                .into_iter()
                .flatten()
                .find(|p| p["name"] == "glb" && p["in"] == "query");
            if path.starts_with("/tilesets/{name}/3dtiles/") {
                let glb = glb.unwrap_or_else(|| panic!("{path}: no glb parameter"));
                let values: Vec<&str> =
                    glb["schema"]["enum"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
                assert_eq!(values, ["none", "meshopt", "draco"], "{path}");
                assert!(values.iter().all(|v| GlbCompression::parse(v).is_some()));
                assert_eq!(glb["schema"]["default"], GlbCompression::default().name());
                let bad = item["get"]["responses"]["400"]["description"].as_str().unwrap();
                assert!(bad.contains("glb="), "{path}: {bad}");
                with.push(path.clone());
            } else {
                assert!(glb.is_none(), "{path} documents glb=");
            }
        }
        assert_eq!(with.len(), 3, "{with:?}");
    }
}
