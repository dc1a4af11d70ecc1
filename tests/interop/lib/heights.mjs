// Check e (expected placed heights of raster samples, per-sample tolerances) and the placement check.
import fs from 'node:fs';
import { createRequire } from 'node:module';
import { invert, multiplyPoint, isIdentity } from './mat4.mjs';
import { readGlbJson, verticalStep, f32Step } from './glb.mjs';

const require = createRequire(import.meta.url);
const { PNG } = require('pngjs');

/** Heights of a terrain-RGB PNG: −10000 + (R·65536 + G·256 + B)·0.1. */
export function readTerrainRgb(file) {
  const png = PNG.sync.read(fs.readFileSync(file));
  const { width, height, data } = png;
  return {
    width,
    height,
    at(col, row) {
      const i = 4 * (row * width + col);
      return -10000 + (data[i] * 65536 + data[i + 1] * 256 + data[i + 2]) * 0.1;
    },
  };
}

/** A k×k grid of (col, row) over the raster, avoiding the outer 2 samples on every side. */
export function sampleGrid(width, height, k) {
  const pick = (n, i) => 2 + Math.round((i * (n - 5)) / (k - 1));
  const out = [];
  for (let j = 0; j < k; j++) for (let i = 0; i < k; i++) out.push({ col: pick(width, i), row: pick(height, j) });
  return out;
}

/** The root tileset's `asset.extras.terrastream.local_frame`, validated. */
export function localFrame(rootJson) {
  const lf = rootJson?.asset?.extras?.terrastream?.local_frame;
  if (!lf) throw new Error('the root tileset.json has no asset.extras.terrastream.local_frame');
  if (!Array.isArray(lf.origin) || lf.origin.length !== 3 || !lf.origin.every(Number.isFinite)) {
    throw new Error(`local_frame.origin is not three numbers: ${JSON.stringify(lf.origin)}`);
  }
  if (lf.north !== '+y' && lf.north !== '-y') throw new Error(`local_frame.north is ${JSON.stringify(lf.north)}, expected "+y" or "-y"`);
  return lf;
}

/** Local east-north-up coordinates of a world point (x, y, h) by the placement rule. */
export function toLocal(lf, x, y, h) {
  const [ox, oy, oz] = lf.origin;
  return [x - ox, lf.north === '+y' ? y - oy : -(y - oy), h - oz];
}

function terrastreamExtras(tile) {
  return tile.extras?.terrastream;
}

/**
 * The tolerance at local (e, n, u): the level-0 mesh error (`errors.max`) of the deepest
 * (largest z) level-0 mesh tile whose box contains (e, n), plus the vertical quantization step
 * of that tile's GLB. Ties (a sample on a shared edge) take the larger tolerance.
 */
export function makeTolerance(walk) {
  const glbByTile = new Map(walk.glbs.map((g) => [g.tile, g]));
  const stepCache = new Map();
  const meshTiles = [];
  for (const t of walk.tiles) {
    const ts = terrastreamExtras(t);
    if (!ts || ts.level !== 0 || ts.kind !== 'mesh') continue;
    const z = Number(String(ts.key ?? '').split('/')[0]);
    const box = t.boundingVolume?.box;
    if (!Array.isArray(box) || box.length !== 12) continue;
    const inv = isIdentity(t.rel) ? null : invert(t.rel);
    meshTiles.push({ t, ts, z, box, inv });
  }
  const stepOf = (t) => {
    if (stepCache.has(t)) return stepCache.get(t);
    const g = glbByTile.get(t);
    let r;
    if (!g) r = { error: `tile ${terrastreamExtras(t)?.key} has no fetched GLB` };
    else {
      try {
        r = verticalStep(readGlbJson(g.buf));
        r.url = g.url;
      } catch (err) {
        r = { error: `${g.url}: ${err.message}` };
      }
    }
    stepCache.set(t, r);
    return r;
  };
  return {
    count: meshTiles.length,
    at(e, n, u) {
      let best = null;
      for (const m of meshTiles) {
        const [px, py] = m.inv ? multiplyPoint(m.inv, [e, n, u]) : [e, n];
        const b = m.box;
        const hx = Math.abs(b[3]) + Math.abs(b[6]) + Math.abs(b[9]);
        const hy = Math.abs(b[4]) + Math.abs(b[7]) + Math.abs(b[10]);
        const eps = 1e-6 * Math.max(1, hx, hy);
        if (Math.abs(px - b[0]) > hx + eps || Math.abs(py - b[1]) > hy + eps) continue;
        const errMax = Number(m.ts.errors?.max);
        const step = stepOf(m.t);
        const cand = { key: m.ts.key, z: m.z, errMax, step: step.step, stepInfo: step, tol: errMax + (step.step ?? NaN) };
        if (!best || m.z > best.z || (m.z === best.z && cand.tol > best.tol)) best = cand;
      }
      return best;
    },
  };
}

/** Whether a 3D Tiles `region` (radians; west > east across the antimeridian) holds a point. */
export function regionContains(region, lonDeg, latDeg) {
  const [w, s, e, n] = region;
  const lon = (lonDeg * Math.PI) / 180, lat = (latDeg * Math.PI) / 180, eps = 1e-12;
  if (lat < s - eps || lat > n + eps) return false;
  return w <= e ? lon >= w - eps && lon <= e + eps : lon >= w - eps || lon <= e + eps;
}

/**
 * The tolerance of a tileset placed on the Earth (region bounding volumes, FLOAT positions) at a
 * longitude and latitude: of the level-0 mesh tiles whose region holds the point, the deepest
 * (largest z; ties take the larger tolerance), its `errors.max` + `margin` + its GLB's f32 step
 * (glb.mjs `f32Step`). Returns `{count, at(lonDeg, latDeg)}`; `at` gives null where no tile holds
 * the point.
 */
export function makeEarthTolerance(walk, margin) {
  const glbByTile = new Map(walk.glbs.map((g) => [g.tile, g]));
  const meshTiles = [];
  for (const t of walk.tiles) {
    const ts = terrastreamExtras(t);
    if (!ts || ts.level !== 0 || ts.kind !== 'mesh') continue;
    const region = t.boundingVolume?.region;
    if (!Array.isArray(region) || region.length !== 6) continue;
    meshTiles.push({ t, ts, z: Number(String(ts.key ?? '').split('/')[0]), region });
  }
  const steps = new Map();
  const stepOf = (t) => {
    if (!steps.has(t)) {
      const g = glbByTile.get(t);
      let r;
      if (!g) r = { error: `tile ${terrastreamExtras(t)?.key} has no fetched GLB` };
      else {
        try {
          r = { ...f32Step(readGlbJson(g.buf)), url: g.url };
        } catch (err) {
          r = { error: `${g.url}: ${err.message}` };
        }
      }
      steps.set(t, r);
    }
    return steps.get(t);
  };
  return {
    count: meshTiles.length,
    at(lonDeg, latDeg) {
      let best = null;
      for (const m of meshTiles) {
        if (!regionContains(m.region, lonDeg, latDeg)) continue;
        const errMax = Number(m.ts.errors?.max);
        const step = stepOf(m.t);
        const cand = { key: m.ts.key, z: m.z, errMax, step: step.step, stepInfo: step, margin, tol: errMax + margin + (step.step ?? NaN) };
        if (!best || m.z > best.z || (m.z === best.z && cand.tol > best.tol)) best = cand;
      }
      return best;
    },
  };
}

// ---------- geodesy (WGS84) for the placement check ----------
const A = 6378137.0;
const F = 1 / 298.257223563;
const E2 = F * (2 - F);

export function ecefToGeodetic([x, y, z]) {
  const lon = Math.atan2(y, x);
  const p = Math.hypot(x, y);
  let lat = Math.atan2(z, p * (1 - E2));
  let h = 0;
  for (let i = 0; i < 10; i++) {
    const s = Math.sin(lat);
    const N = A / Math.sqrt(1 - E2 * s * s);
    h = p / Math.cos(lat) - N;
    lat = Math.atan2(z, p * (1 - (E2 * N) / (N + h)));
  }
  return { lon: (lon * 180) / Math.PI, lat: (lat * 180) / Math.PI, h };
}

function enuColumns(lonDeg, latDeg) {
  const l = (lonDeg * Math.PI) / 180;
  const p = (latDeg * Math.PI) / 180;
  return [
    [-Math.sin(l), Math.cos(l), 0],
    [-Math.sin(p) * Math.cos(l), -Math.sin(p) * Math.sin(l), Math.cos(p)],
    [Math.cos(p) * Math.cos(l), Math.cos(p) * Math.sin(l), Math.sin(p)],
  ];
}

/**
 * Checks the root transform: an east-north-up frame at its own origin (orthonormal, no scale),
 * and the centre of the data at height 0 (`centreLocal`, its local coordinates by the placement
 * rule) placed at the anchor (`bake --anchor`: "the centre of the data, at height 0, is placed
 * there"). Returns detail lines and problems.
 */
export function checkPlacement(rootJson, anchor, centreLocal) {
  const lines = [];
  const problems = [];
  const T = rootJson?.root?.transform;
  if (!Array.isArray(T) || T.length !== 16 || !T.every(Number.isFinite)) {
    problems.push(`root.transform is ${T === undefined ? 'missing' : 'not 16 finite numbers'}`);
    return { lines, problems };
  }
  if (Math.abs(T[3]) + Math.abs(T[7]) + Math.abs(T[11]) > 1e-12 || Math.abs(T[15] - 1) > 1e-12) {
    problems.push(`root.transform's last row is [${T[3]}, ${T[7]}, ${T[11]}, ${T[15]}], expected [0, 0, 0, 1]`);
  }
  const origin = [T[12], T[13], T[14]];
  const g = ecefToGeodetic(origin);
  lines.push(`root.transform origin: ECEF (${origin.map((v) => v.toFixed(3)).join(', ')}) = lon ${g.lon.toFixed(8)}°, lat ${g.lat.toFixed(8)}°, h ${g.h.toFixed(3)} m`);
  const enu = enuColumns(g.lon, g.lat);
  const names = ['east', 'north', 'up'];
  let worst = 0;
  for (let c = 0; c < 3; c++) {
    const col = [T[4 * c], T[4 * c + 1], T[4 * c + 2]];
    const d = Math.max(...col.map((v, k) => Math.abs(v - enu[c][k])));
    worst = Math.max(worst, d);
    if (d > 1e-6) problems.push(`root.transform column ${c} is (${col.map((v) => v.toFixed(9)).join(', ')}), the ${names[c]} unit vector at the origin is (${enu[c].map((v) => v.toFixed(9)).join(', ')})`);
  }
  lines.push(`rotation vs east-north-up at the origin: largest difference ${worst.toExponential(2)}`);
  const c = ecefToGeodetic(multiplyPoint(T, centreLocal));
  const aH = anchor.h ?? 0;
  const metres = Math.hypot((c.lon - anchor.lon) * 111320 * Math.cos((anchor.lat * Math.PI) / 180), (c.lat - anchor.lat) * 110540);
  lines.push(`centre of the data at height 0, local (${centreLocal.map((v) => v.toFixed(2)).join(', ')}): lon ${c.lon.toFixed(8)}°, lat ${c.lat.toFixed(8)}°, h ${c.h.toFixed(3)} m`);
  lines.push(`anchor lon ${anchor.lon}, lat ${anchor.lat}, h ${aH}: ${metres.toFixed(3)} m away horizontally, ${(c.h - aH).toFixed(3)} m vertically`);
  if (metres > 0.05) problems.push(`the centre of the data is placed ${metres.toFixed(2)} m from the anchor (${anchor.lon}, ${anchor.lat}): at lon ${c.lon.toFixed(8)}, lat ${c.lat.toFixed(8)}`);
  if (Math.abs(c.h - aH) > 0.05) problems.push(`the centre of the data at height 0 is placed at ellipsoidal height ${c.h.toFixed(3)} m, the anchor's is ${aH} m`);
  return { lines, problems, origin: g };
}
