//! The OpenAPI 3.1 document served at `/openapi.json`, written by hand to match the routes.

use serde_json::{Value, json};

fn problem(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}}})
}

fn name_param() -> Value {
    json!({"name": "name", "in": "path", "required": true, "schema": {"type": "string", "pattern": "^[a-z0-9_-]{1,64}$"}})
}

fn int_param(n: &str) -> Value {
    json!({"name": n, "in": "path", "required": true, "schema": {"type": "integer", "minimum": 0}})
}

fn v_param() -> Value {
    json!({"name": "v", "in": "query", "required": false, "schema": {"type": "string"},
        "description": "The tileset's content_version. When it matches, the response is `Cache-Control: public, max-age=31536000, immutable`; otherwise it is revalidated after 60 s."})
}

#[must_use]
pub fn document() -> Value {
    let errors = |extra: &[(&str, &str)]| {
        let mut m = serde_json::Map::new();
        m.insert("400".into(), problem("Malformed name or key, or z/x/y/level out of range"));
        m.insert("404".into(), problem("Unknown tileset, or a tile outside the data"));
        m.insert("429".into(), problem("Rate limited (Retry-After)"));
        m.insert("503".into(), problem("Overloaded, bake queue full or timed out (Retry-After)"));
        for (k, v) in extra {
            m.insert((*k).into(), problem(v));
        }
        Value::Object(m)
    };
    let cached = |desc: &str, ctype: &str| {
        json!({"description": desc, "headers": {
            "ETag": {"schema": {"type": "string"}}, "Cache-Control": {"schema": {"type": "string"}}},
            "content": {ctype: {}}})
    };
    let with = |mut base: Value, ok: Value| {
        if let Some(o) = base.as_object_mut() {
            o.insert("200".into(), ok);
            o.insert("304".into(), json!({"description": "Not modified (If-None-Match)"}));
        }
        base
    };
    json!({
        "openapi": "3.1.0",
        "info": {"title": "terrastream", "version": env!("CARGO_PKG_VERSION"),
            "description": "Tiled terrain LOD (TIN mesh + point-cloud levels) over HTTP."},
        "paths": {
            "/healthz": {"get": {"summary": "Alive", "responses": {"200": {"description": "alive"}}}},
            "/readyz": {"get": {"summary": "Store readable and tilesets loaded", "responses": {"200": {"description": "ready"}, "503": problem("not ready")}}},
            "/metrics": {"get": {"summary": "Prometheus metrics", "responses": {"200": {"description": "text/plain; version=0.0.4"}}}},
            "/tilesets": {"get": {"summary": "Tilesets served, with manifest summaries", "responses": with(errors(&[]), cached("list", "application/json"))}},
            "/tilesets/{name}": {
                "parameters": [name_param()],
                "get": {"summary": "One tileset's summary", "responses": with(errors(&[]), cached("summary", "application/json"))},
                "post": {"summary": "Admin: upload a raster and bake it as a new tileset",
                    "security": [{"admin": []}],
                    "parameters": [
                        {"name": "encoding", "in": "query", "schema": {"enum": ["gray16", "terrain-rgb", "terrarium"]}},
                        {"name": "cell_size", "in": "query", "schema": {"type": "number"}},
                        {"name": "tile_size", "in": "query", "schema": {"type": "integer"}},
                        {"name": "max_error", "in": "query", "schema": {"type": "number"}},
                        {"name": "levels", "in": "query", "schema": {"type": "integer"}}],
                    "requestBody": {"content": {"application/octet-stream": {}}},
                    "responses": errors(&[("202", "Job started (Location: /jobs/{id})"), ("401", "No token"), ("403", "Wrong token or admin API disabled"), ("409", "Tileset exists"), ("413", "Upload too large")])},
                "delete": {"summary": "Admin: delete a tileset", "security": [{"admin": []}],
                    "responses": errors(&[("204", "Deleted"), ("401", "No token"), ("403", "Wrong token"), ("409", "On-demand tileset")])}
            },
            "/tilesets/{name}/tileset.json": {"get": {"summary": "Manifest", "parameters": [name_param()],
                "responses": with(errors(&[("206", "Range"), ("416", "Range not satisfiable")]), cached("manifest", "application/json"))}},
            "/tilesets/{name}/index/{z}/{x}/{y}.json": {"get": {"summary": "Index chunk rooted at a z multiple of 4",
                "parameters": [name_param(), int_param("z"), int_param("x"), int_param("y"), v_param()],
                "responses": with(errors(&[("206", "Range"), ("416", "Range not satisfiable")]), cached("index chunk", "application/json"))}},
            "/tilesets/{name}/tiles/{z}/{x}/{y}/{level}": {"get": {"summary": "One blob (baked on first request for --source tilesets)",
                "parameters": [name_param(), int_param("z"), int_param("x"), int_param("y"), int_param("level"), v_param()],
                "responses": with(errors(&[("206", "Range"), ("416", "Range not satisfiable"), ("500", "Stored blob failed its checksum (never sent) or bake failed")]),
                    cached("blob", "application/vnd.terrastream.blob"))}},
            "/jobs/{id}": {"get": {"summary": "Admin: bake job progress", "security": [{"admin": []}],
                "parameters": [{"name": "id", "in": "path", "required": true, "schema": {"type": "string"}}],
                "responses": errors(&[("200", "Job state"), ("401", "No token"), ("403", "Wrong token")])}}
        },
        "components": {
            "securitySchemes": {"admin": {"type": "http", "scheme": "bearer"}, "read": {"type": "http", "scheme": "bearer"}},
            "schemas": {"Problem": {"type": "object", "properties": {
                "type": {"type": "string"}, "title": {"type": "string"}, "status": {"type": "integer"}, "detail": {"type": "string"}}}}
        }
    })
}
