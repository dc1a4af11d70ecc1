// Walks a 3D Tiles tileset over HTTP: tileset JSONs, external tilesets, GLB contents.
import { fetchWithTimeout } from './proc.mjs';
import { IDENTITY, multiply } from './mat4.mjs';

const MAX_FETCHES = 4000;
const PARALLEL = 6;

/** A tiny semaphore so a big tileset is fetched a few requests at a time. */
function limiter(n) {
  let active = 0;
  const queue = [];
  const next = () => {
    if (active >= n || queue.length === 0) return;
    active++;
    const { fn, resolve, reject } = queue.shift();
    fn().then(resolve, reject).finally(() => {
      active--;
      next();
    });
  };
  return (fn) => new Promise((resolve, reject) => {
    queue.push({ fn, resolve, reject });
    next();
  });
}

/**
 * Walks the tileset at `rootUrl`. Returns
 * {rootUrl, rootJson, jsons: [{url, json, parentUrl}], glbs: [{url, buf, tile}],
 *  tiles: [{tileset, path, depth, world, rel, boundingVolume, geometricError, extras, contentUrl, contentKind}],
 *  errors: [string], notes: [string], fetches}
 * `world` is the tile's accumulated transform (root transform included), `rel` the same
 * without the root tileset's root transform (the frame of the root tile's local coordinates).
 */
export async function walkTileset(rootUrl) {
  const limit = limiter(PARALLEL);
  const out = { rootUrl, rootJson: null, jsons: [], glbs: [], tiles: [], errors: [], notes: [], fetches: 0 };
  const seen = new Set();
  let noVersion = 0;

  async function get(url) {
    if (++out.fetches > MAX_FETCHES) throw new Error(`more than ${MAX_FETCHES} fetches: stopped`);
    return limit(async () => {
      const res = await fetchWithTimeout(url, { timeoutMs: 60_000 });
      const buf = Buffer.from(await res.arrayBuffer());
      return { res, buf };
    });
  }

  async function visitJson(url, parentWorld, parentRel, depth, parentUrl) {
    if (seen.has(url)) {
      out.errors.push(`${url} is referenced twice (a cycle or a duplicate external tileset)`);
      return;
    }
    seen.add(url);
    let res, buf;
    try {
      ({ res, buf } = await get(url));
    } catch (err) {
      out.errors.push(`GET ${url} failed: ${err.cause?.code || err.message}`);
      return;
    }
    if (res.status !== 200) {
      out.errors.push(`GET ${url} -> ${res.status} ${truncate(buf.toString('utf8'), 300)}`);
      return;
    }
    let json;
    try {
      json = JSON.parse(buf.toString('utf8'));
    } catch (err) {
      out.errors.push(`${url}: not JSON (${err.message}); content-type ${res.headers.get('content-type')}`);
      return;
    }
    if (!out.rootJson) out.rootJson = json;
    out.jsons.push({ url, json, parentUrl });
    if (!json.asset || typeof json.asset.version !== 'string') out.errors.push(`${url}: asset.version missing`);
    else if (!['1.0', '1.1'].includes(json.asset.version)) out.errors.push(`${url}: asset.version ${json.asset.version}`);
    if (typeof json.geometricError !== 'number') out.errors.push(`${url}: top-level geometricError missing`);
    if (!json.root) {
      out.errors.push(`${url}: no root tile`);
      return;
    }
    const jobs = [];
    const visitTile = (tile, world, rel, d, pathStr) => {
      if (tile.transform) {
        if (!Array.isArray(tile.transform) || tile.transform.length !== 16) {
          out.errors.push(`${url} ${pathStr}: transform is not 16 numbers`);
        } else {
          world = multiply(world, tile.transform);
          // the root tileset's root transform places the local frame; anything below is relative to it
          rel = depth === 0 && pathStr === 'root' ? rel : multiply(rel, tile.transform);
        }
      }
      if (tile.implicitTiling || tile.extensions?.['3DTILES_implicit_tiling']) {
        out.errors.push(`${url} ${pathStr}: implicit tiling is not walked by this harness`);
      }
      if (!tile.boundingVolume) out.errors.push(`${url} ${pathStr}: no boundingVolume`);
      if (typeof tile.geometricError !== 'number') out.errors.push(`${url} ${pathStr}: no geometricError`);
      const contents = tile.content ? [tile.content] : Array.isArray(tile.contents) ? tile.contents : [];
      const entry = {
        tileset: url, path: pathStr, depth: d, world, rel, boundingVolume: tile.boundingVolume,
        geometricError: tile.geometricError, extras: tile.extras ?? tile.content?.extras, contentUrl: null, contentKind: null,
      };
      out.tiles.push(entry);
      for (const content of contents) {
        const uri = content.uri ?? content.url;
        if (typeof uri !== 'string') {
          out.errors.push(`${url} ${pathStr}: content without uri`);
          continue;
        }
        let abs;
        try {
          abs = new URL(uri, url).href;
        } catch {
          out.errors.push(`${url} ${pathStr}: content uri ${JSON.stringify(uri)} does not resolve`);
          continue;
        }
        if (new URL(abs).host !== new URL(rootUrl).host) {
          // never fetched: nothing of this harness leaves the server under test
          out.errors.push(`${url} ${pathStr}: content ${abs} is not on the server (${new URL(rootUrl).host})`);
          continue;
        }
        if (!new URL(abs).searchParams.has('v')) noVersion++;
        const pathname = new URL(abs).pathname;
        entry.contentUrl = abs;
        if (pathname.endsWith('.json')) {
          entry.contentKind = 'json';
          jobs.push(visitJson(abs, world, rel, d + 1, url));
        } else if (pathname.endsWith('.glb')) {
          entry.contentKind = 'glb';
          jobs.push(visitGlb(abs, entry));
        } else {
          out.errors.push(`${url} ${pathStr}: content ${abs} is neither .glb nor .json`);
        }
      }
      (tile.children ?? []).forEach((child, i) => visitTile(child, world, rel, d + 1, `${pathStr}.children[${i}]`));
    };
    visitTile(json.root, parentWorld, parentRel, depth, 'root');
    await Promise.all(jobs);
  }

  async function visitGlb(url, tile) {
    if (seen.has(url)) {
      out.notes.push(`${url} is the content of more than one tile`);
      return;
    }
    seen.add(url);
    let res, buf;
    try {
      ({ res, buf } = await get(url));
    } catch (err) {
      out.errors.push(`GET ${url} failed: ${err.cause?.code || err.message}`);
      return;
    }
    if (res.status !== 200) {
      out.errors.push(`GET ${url} -> ${res.status} ${truncate(buf.toString('utf8'), 300)}`);
      return;
    }
    if (buf.toString('latin1', 0, 4) !== 'glTF') {
      out.errors.push(`${url}: not a GLB (first bytes ${JSON.stringify(buf.toString('latin1', 0, 4))}, content-type ${res.headers.get('content-type')})`);
    }
    out.glbs.push({ url, buf, tile, contentType: res.headers.get('content-type') });
  }

  try {
    await visitJson(rootUrl, IDENTITY, IDENTITY, 0, null);
  } catch (err) {
    out.errors.push(err.message);
  }
  if (noVersion) out.notes.push(`${noVersion} content URIs carry no ?v=`);
  out.glbs.sort((a, b) => a.url.localeCompare(b.url));
  return out;
}

export function truncate(s, n) {
  s = String(s).replace(/\s+/g, ' ');
  return s.length > n ? `${s.slice(0, n)}…` : s;
}
