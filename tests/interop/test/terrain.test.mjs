// Unit tests of lib/terrain.mjs, the quantized-mesh checks' own helpers (`node --test test/`).
// References: CesiumJS's own code run here (oct normals, the geodetic tiling, horizon culling,
// bounding spheres), PROJ (`gdaltransform`), and tiles written below by a small encoder that
// follows the quantized-mesh-1.0 spec (zig-zag deltas, high-water-mark indices, extensions), so
// that each check is seen both to pass a right tile and to fail a wrong one.
import test from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { createRequire } from 'node:module';
import {
  QMAX, octDecode, tileRect, layerTiles, rangesDiff, clipRanges, decodeTile, checkTile, crackTest, compareEdge, tileKey,
  scaledPointVisible, RADII, bilinearAt, pixelOf, fromLonLat, snapToSamples, sampleStep, halfUvStep,
} from '../lib/terrain.mjs';
import { ecefOf, toLonLat } from '../lib/earth.mjs';

const require = createRequire(import.meta.url);
const Cesium = require('cesium');

// ---------- a spec encoder for test tiles ----------

const zz = (v) => ((v << 1) ^ (v >> 31)) & 0xffff;

/**
 * Encodes a quantized-mesh-1.0 tile: `verts` [[u, v, hq]] (renumbered in their first use by
 * `tris`), the header (fields as @here/quantized-mesh-decoder names them), edge lists, and
 * extensions: normals (bytes), watermask (bytes), metadata (object).
 */
function encodeQm(tile) {
  // vertices renumbered in first-use order (what the high-water-mark code needs)
  const map = new Map();
  for (const t of tile.tris) for (const i of t) if (!map.has(i)) map.set(i, map.size);
  const old = [...map.keys()];
  const tris = tile.tris.map((t) => t.map((i) => map.get(i)));
  const verts = old.map((i) => tile.verts[i]);
  // (normalsRaw: bytes as they are, for a wrong length)
  const normals = tile.normalsRaw ?? (tile.normals && old.flatMap((i) => [tile.normals[2 * i], tile.normals[2 * i + 1]]));
  const edges = Object.fromEntries(Object.entries(tile.edges).map(([k, l]) => [k, l.map((i) => map.get(i))]));
  const { header, watermask, metadata } = tile;
  const n = verts.length;
  const parts = [];
  const hb = Buffer.alloc(88);
  const f64 = ['centerX', 'centerY', 'centerZ'];
  f64.forEach((k, i) => hb.writeDoubleLE(header[k], 8 * i));
  hb.writeFloatLE(header.minHeight, 24);
  hb.writeFloatLE(header.maxHeight, 28);
  ['boundingSphereCenterX', 'boundingSphereCenterY', 'boundingSphereCenterZ', 'boundingSphereRadius', 'horizonOcclusionPointX', 'horizonOcclusionPointY', 'horizonOcclusionPointZ']
    .forEach((k, i) => hb.writeDoubleLE(header[k], 32 + 8 * i));
  parts.push(hb);
  const count = Buffer.alloc(4);
  count.writeUInt32LE(n);
  parts.push(count);
  for (let c = 0; c < 3; c++) {
    const b = Buffer.alloc(2 * n);
    let prev = 0;
    verts.forEach((vv, i) => {
      b.writeUInt16LE(zz(vv[c] - prev), 2 * i);
      prev = vv[c];
    });
    parts.push(b);
  }
  const tb = Buffer.alloc(4 + 6 * tris.length);
  tb.writeUInt32LE(tris.length);
  let highest = 0, o = 4;
  for (const t of tris) for (const i of t) {
    tb.writeUInt16LE(highest - i, o);
    o += 2;
    if (i === highest) highest++;
  }
  parts.push(tb);
  for (const side of ['west', 'south', 'east', 'north']) {
    const l = edges[side];
    const b = Buffer.alloc(4 + 2 * l.length);
    b.writeUInt32LE(l.length);
    l.forEach((k, i) => b.writeUInt16LE(k, 4 + 2 * i));
    parts.push(b);
  }
  const ext = (id, body) => {
    const h = Buffer.alloc(5);
    h.writeUInt8(id);
    h.writeUInt32LE(body.length, 1);
    parts.push(h, body);
  };
  if (normals) ext(1, Buffer.from(normals));
  if (watermask) ext(2, Buffer.from(watermask));
  if (metadata) {
    const json = Buffer.from(JSON.stringify(metadata));
    const len = Buffer.alloc(4);
    len.writeUInt32LE(json.length);
    ext(4, Buffer.concat([len, json]));
  }
  return Buffer.concat(parts);
}

/**
 * A 3×3-vertex tile (z, x, y) with heights `hm` (metres, 9 values, row-major from the south-west)
 * and a right header: Cesium's BoundingSphere.fromPoints and EllipsoidalOccluder horizon point,
 * normals = the ellipsoid's up (Cesium's octEncode).
 */
function gridTile({ z, x, y, hm, metadata, range = [Math.min(...hm), Math.max(...hm) + 1], mutate = (t) => t }) {
  const rect = tileRect(z, x, y);
  const [min, max] = range;
  const q = [0, 16384, QMAX];
  // vertices in first-use order of these triangles (counter-clockwise in u, v)
  const grid = [];
  for (let j = 0; j < 3; j++) for (let i = 0; i < 3; i++) grid.push([q[i], q[j], Math.round(((hm[3 * j + i] - min) / (max - min)) * QMAX)]);
  const quads = [];
  for (let j = 0; j < 2; j++) for (let i = 0; i < 2; i++) {
    const a = 3 * j + i, b = a + 1, c = a + 4, d = a + 3;
    quads.push([a, b, c], [a, c, d]);
  }
  const order = [], index = new Map();
  const tris = quads.map((t) => t.map((g) => {
    if (!index.has(g)) {
      index.set(g, order.length);
      order.push(g);
    }
    return index.get(g);
  }));
  const verts = order.map((g) => grid[g]);
  const lonlat = (vv) => [rect.west + (vv[0] / QMAX) * (rect.east - rect.west), rect.south + (vv[1] / QMAX) * (rect.north - rect.south)];
  const pts = verts.map((vv) => {
    const [lon, lat] = lonlat(vv);
    return Cesium.Cartesian3.fromDegrees(lon, lat, min + (vv[2] / QMAX) * (max - min));
  });
  const bs = Cesium.BoundingSphere.fromPoints(pts);
  const occluder = new Cesium.EllipsoidalOccluder(Cesium.Ellipsoid.WGS84);
  // none exists for a hemisphere (zoom 0): a point far out, never culled
  const hp = occluder.computeHorizonCullingPoint(bs.center, pts) ?? Cesium.Cartesian3.multiplyByScalar(Cesium.Cartesian3.normalize(bs.center, new Cesium.Cartesian3()), 1e6, new Cesium.Cartesian3());
  const centre = Cesium.Cartesian3.fromDegrees((rect.west + rect.east) / 2, (rect.south + rect.north) / 2, (min + max) / 2);
  const normals = [];
  for (const vv of verts) {
    const [lon, lat] = lonlat(vv);
    const up = Cesium.Ellipsoid.WGS84.geodeticSurfaceNormalCartographic(Cesium.Cartographic.fromDegrees(lon, lat));
    const e = Cesium.AttributeCompression.octEncode(up, new Cesium.Cartesian2());
    normals.push(e.x, e.y);
  }
  const edges = { west: [], south: [], east: [], north: [] };
  verts.forEach((vv, k) => {
    if (vv[0] === 0) edges.west.push(k);
    if (vv[1] === 0) edges.south.push(k);
    if (vv[0] === QMAX) edges.east.push(k);
    if (vv[1] === QMAX) edges.north.push(k);
  });
  const t = {
    header: {
      centerX: centre.x, centerY: centre.y, centerZ: centre.z, minHeight: min, maxHeight: max,
      boundingSphereCenterX: bs.center.x, boundingSphereCenterY: bs.center.y, boundingSphereCenterZ: bs.center.z, boundingSphereRadius: bs.radius,
      horizonOcclusionPointX: hp.x, horizonOcclusionPointY: hp.y, horizonOcclusionPointZ: hp.z,
    },
    verts, tris, edges, normals, watermask: [0], metadata,
  };
  return encodeQm(mutate(t));
}

const LAYER = { available: [[{ startX: 0, startY: 0, endX: 1, endY: 0 }]], metadataAvailability: 10 };

// ---------- CesiumJS as the reference ----------

test('octDecode is CesiumJS AttributeCompression.octDecode for every byte pair', () => {
  const r = new Cesium.Cartesian3();
  for (let x = 0; x < 256; x++) for (let y = 0; y < 256; y++) {
    const c = Cesium.AttributeCompression.octDecode(x, y, r);
    const m = octDecode(x, y);
    assert.ok(Math.abs(c.x - m[0]) < 1e-12 && Math.abs(c.y - m[1]) < 1e-12 && Math.abs(c.z - m[2]) < 1e-12, `${x}, ${y}`);
  }
});

test('tileRect is CesiumJS GeographicTilingScheme (y counted from the south, TMS)', () => {
  const ts = new Cesium.GeographicTilingScheme();
  for (const [z, x, y] of [[0, 0, 0], [0, 1, 0], [3, 5, 2], [11, 2170, 1555], [14, 32767, 0]]) {
    const c = ts.tileXYToRectangle(x, 2 ** z - 1 - y, z);
    const m = tileRect(z, x, y);
    for (const [k, v] of Object.entries({ west: c.west, south: c.south, east: c.east, north: c.north })) {
      assert.ok(Math.abs(Cesium.Math.toDegrees(v) - m[k]) < 1e-9, `${z}/${x}/${y} ${k}`);
    }
  }
});

test('scaledPointVisible is CesiumJS EllipsoidalOccluder.isScaledSpacePointVisible', () => {
  const occ = new Cesium.EllipsoidalOccluder(Cesium.Ellipsoid.WGS84);
  let seed = 11;
  const rnd = () => (seed = (seed * 1103515245 + 12345) % 2 ** 31) / 2 ** 31;
  let visible = 0;
  for (let i = 0; i < 2000; i++) {
    const cam = ecefOf(rnd() * 360 - 180, rnd() * 180 - 90, 10 ** (2 + rnd() * 5));
    const pt = ecefOf(rnd() * 360 - 180, rnd() * 180 - 90, rnd() * 9000);
    occ.cameraPosition = new Cesium.Cartesian3(...cam);
    const sc = pt.map((v, k) => v / RADII[k]);
    const want = occ.isScaledSpacePointVisible(new Cesium.Cartesian3(...sc));
    assert.equal(scaledPointVisible(sc, cam.map((v, k) => v / RADII[k])), want, `camera ${cam}, point ${pt}`);
    if (want) visible++;
  }
  assert.ok(visible > 100 && visible < 1900, `both outcomes exercised (${visible} visible)`);
});

// ---------- decoding and the per-tile checks ----------

const HM = [1000, 1100, 1200, 1050, 1500, 1250, 1100, 1300, 1400];

test('a right tile decodes (@here/quantized-mesh-decoder) and passes every check', () => {
  const id = { z: 12, x: 4330, y: 2055 };
  const t = decodeTile(gridTile({ ...id, hm: HM }));
  assert.equal(t.n, 9);
  assert.equal(t.triangles.length, 24);
  assert.deepEqual(t.layout.extensions.map((e) => e.id), [1, 2]);
  const r = checkTile(t, id, LAYER, { wantMetadataAt: 10 });
  assert.deepEqual(r.problems, []);
  assert.ok(r.figures.horizonMag > 1 && r.figures.horizonMag < 1.01, `${r.figures.horizonMag}`);
  assert.ok(r.figures.horizonCulledCameras > 0, 'some cameras cull the tile');
  assert.ok(r.figures.minUpDot > 0.999);
});

test('each wrong tile fails its check, named', () => {
  const id = { z: 12, x: 4330, y: 2055 };
  const problemsOf = (mutate, opts = {}) => checkTile(decodeTile(gridTile({ ...id, hm: HM, mutate })), id, LAYER, { wantMetadataAt: 10, ...opts }).problems.join('\n');
  // clockwise triangles
  assert.match(problemsOf((t) => ({ ...t, tris: t.tris.map(([a, b, c]) => [a, c, b]) })), /clockwise/);
  // a vertex on the west edge left out of its edge list
  assert.match(problemsOf((t) => ({ ...t, edges: { ...t.edges, west: t.edges.west.slice(1) } })), /missing from its edge list/);
  // a vertex named on an edge it is not on
  assert.match(problemsOf((t) => ({ ...t, edges: { ...t.edges, north: [...t.edges.north, t.edges.south.find((k) => !t.edges.north.includes(k))] } })), /not on the north edge/);
  // a bounding sphere 10 m too small
  assert.match(problemsOf((t) => ({ ...t, header: { ...t.header, boundingSphereRadius: t.header.boundingSphereRadius - 10 } })), /bounding sphere/);
  // the horizon point in metres (the classic mistake), and one too low (culls a visible tile)
  const hp = (t, f) => ({ ...t, header: { ...t.header, horizonOcclusionPointX: t.header.horizonOcclusionPointX * f, horizonOcclusionPointY: t.header.horizonOcclusionPointY * f, horizonOcclusionPointZ: t.header.horizonOcclusionPointZ * f } });
  assert.match(problemsOf((t) => hp(t, RADII[0])), /not in ellipsoid-scaled units/);
  assert.match(problemsOf((t) => hp(t, 1 / Math.hypot(t.header.horizonOcclusionPointX, t.header.horizonOcclusionPointY, t.header.horizonOcclusionPointZ))), /would cull a visible tile/);
  // normals pointing down
  assert.match(problemsOf((t) => {
    const down = [];
    for (let k = 0; k < t.verts.length; k++) {
      const [bx, by] = [t.normals[2 * k], t.normals[2 * k + 1]];
      const n = octDecode(bx, by).map((c) => -c);
      const e = Cesium.AttributeCompression.octEncode(new Cesium.Cartesian3(...n), new Cesium.Cartesian2());
      down.push(e.x, e.y);
    }
    return { ...t, normals: down };
  }), /into the ground/);
  // no normals at all
  assert.match(problemsOf((t) => ({ ...t, normals: null })), /no octvertexnormals/);
});

test('the layout is walked by the spec: bad extension lengths and trailing bytes are refused', () => {
  const id = { z: 12, x: 4330, y: 2055 };
  assert.throws(() => decodeTile(gridTile({ ...id, hm: HM, mutate: (t) => ({ ...t, normalsRaw: t.normals.slice(2) }) })), /2 per vertex/);
  assert.throws(() => decodeTile(gridTile({ ...id, hm: HM, mutate: (t) => ({ ...t, watermask: [0, 0, 0] }) })), /watermask/);
  const good = gridTile({ ...id, hm: HM });
  assert.throws(() => decodeTile(Buffer.concat([good, Buffer.from([7, 7])])), /truncated|outside the bounds/);
  // a metadata extension whose JSON length prefix is wrong
  const meta = gridTile({ ...id, hm: HM, metadata: { available: [] } });
  const at = meta.length - JSON.stringify({ available: [] }).length - 4;
  meta.writeUInt32LE(meta.readUInt32LE(at) + 1, at);
  assert.throws(() => decodeTile(meta), /./);
});

test('the metadata extension must equal layer.json availability of the tile\'s descendants', () => {
  const layer = {
    metadataAvailability: 10,
    available: Array.from({ length: 13 }, (_, z) => (z < 10 ? [{ startX: 0, startY: 0, endX: 2 ** (z + 1) - 1, endY: 2 ** z - 1 }] : [])),
  };
  // zoom 10 tile (4330 >> 0, …): descendants at 11 and 12 that exist
  layer.available[10] = [{ startX: 2164, startY: 1027, endX: 2166, endY: 1028 }];
  layer.available[11] = [{ startX: 4330, startY: 2055, endX: 4333, endY: 2056 }];
  layer.available[12] = [{ startX: 8662, startY: 4111, endX: 8664, endY: 4112 }];
  const id = { z: 10, x: 2165, y: 1028 };
  const k1 = { startX: 4330, startY: 2056, endX: 4331, endY: 2056 };
  const k2 = { startX: 8662, startY: 4112, endX: 8663, endY: 4112 };
  const meta = (available) => checkTile(decodeTile(gridTile({ ...id, hm: HM, metadata: { available } })), id, layer, { wantMetadataAt: 10 }).problems.join('\n');
  assert.equal(meta([[k1], [k2]]), '');
  // the same tiles cut differently still agree
  assert.equal(meta([[{ ...k1, endX: 4330 }, { ...k1, startX: 4331 }], [k2]]), '');
  assert.match(meta([[k1], []]), /zoom 12 differs/);
  assert.match(meta([[{ ...k1, startX: 4329 }], [k2]]), /tile 11\/4329\/2056 is in the metadata only/);
  assert.match(checkTile(decodeTile(gridTile({ ...id, hm: HM })), id, layer, { wantMetadataAt: 10 }).problems.join('\n'), /no metadata extension/);
});

test('rangesDiff and clipRanges: sets of tiles, however cut', () => {
  const a = [{ startX: 0, startY: 0, endX: 9, endY: 4 }];
  const b = [{ startX: 0, startY: 0, endX: 4, endY: 4 }, { startX: 5, startY: 0, endX: 9, endY: 2 }, { startX: 5, startY: 3, endX: 9, endY: 4 }];
  assert.equal(rangesDiff(a, b), null);
  assert.deepEqual(rangesDiff(a, b.slice(0, 2)), { x: 5, y: 3, inA: true });
  assert.equal(rangesDiff([], []), null);
  assert.deepEqual(clipRanges(a, 8, 4, 20, 20), [{ startX: 8, startY: 4, endX: 9, endY: 4 }]);
  assert.deepEqual(clipRanges(a, 10, 0, 20, 20), []);
  assert.equal(layerTiles({ available: [[{ startX: 0, startY: 0, endX: 1, endY: 0 }], b] }).length, 2 + 50);
});

// ---------- the crack test ----------

test('the crack test: shared edges alike pass; a height, a missing vertex or a normal fails, named', () => {
  // west tile x, east tile x+1: the east column of one is the west column of the other
  const W = [1000, 1100, 1200, 1050, 1500, 1250, 1100, 1300, 1400];
  const E = [1200, 900, 800, 1250, 1000, 700, 1400, 1100, 900];
  // one height range for both, so the same metres quantize alike
  const build = (x, hm, mutate) => decodeTile(gridTile({ z: 12, x, y: 2055, hm, range: [0, 2048], mutate }));
  const ok = new Map([[tileKey(12, 4330, 2055), build(4330, W)], [tileKey(12, 4331, 2055), build(4331, E)]]);
  const r = crackTest(ok);
  assert.deepEqual(r.problems, []);
  assert.equal(r.ew, 1);
  assert.equal(r.ns, 0);
  assert.equal(r.vertices, 3);
  assert.equal(r.worstDh, 0);
  // 2 m higher on one side
  const E2 = [...E];
  E2[3] += 2;
  const bad = crackTest(new Map([[tileKey(12, 4330, 2055), build(4330, W)], [tileKey(12, 4331, 2055), build(4331, E2)]]));
  assert.match(bad.problems.join('\n'), /12\/4330\/2055 east edge vs 12\/4331\/2055 west edge: 1 shared vertices differ in height/);
  // a vertex on one side only (moved off the edge in the east tile): a T-junction
  const moved = build(4331, E, (t) => {
    const verts = t.verts.map((vv) => (vv[0] === 0 && vv[1] === 16384 ? [40, vv[1], vv[2]] : vv));
    return { ...t, verts, edges: { ...t.edges, west: t.edges.west.filter((k) => verts[k][0] === 0) } };
  });
  const tj = crackTest(new Map([[tileKey(12, 4330, 2055), build(4330, W)], [tileKey(12, 4331, 2055), moved]]));
  assert.match(tj.problems.join('\n'), /on one side only/);
  // a normal that differs
  const turned = build(4331, E, (t) => {
    const k = t.edges.west[1];
    const normals = [...t.normals];
    normals[2 * k] = (normals[2 * k] + 9) % 256;
    return { ...t, normals };
  });
  const tn = compareEdge(ok.get('12/4330/2055'), 'east', turned, 'west', { nameA: 'a', nameB: 'b' });
  assert.match(tn.problems.join('\n'), /different normals/);
});

test('the crack test pairs the antimeridian: x = last with x = 0', () => {
  // zoom 0: tile 1 (0°…180°) east edge meets tile 0 (−180°…0°) west edge
  const hm = [10, 20, 30, 10, 50, 30, 10, 20, 30];
  const west = decodeTile(gridTile({ z: 0, x: 0, y: 0, hm: [30, 5, 5, 30, 5, 5, 30, 5, 5] }));
  const east = decodeTile(gridTile({ z: 0, x: 1, y: 0, hm }));
  const r = crackTest(new Map([['0/0/0', west], ['0/1/0', east]]));
  assert.equal(r.antimeridian, 1);
  assert.equal(r.ew, 2);
});

// ---------- expected heights ----------

/** A synthetic raster: h = 100 + 0.2·x − 0.1·y on a 10 m grid, origin (500000, 5100000), north up. */
function planeRaster() {
  const x0 = 500000, y0 = 5100000, d = 10;
  return {
    width: 50, height: 40, epsg: 32632,
    world: (c, r) => [x0 + c * d, y0 - r * d],
    at: (c, r) => 100 + 0.2 * (x0 + c * d - 500000) - 0.1 * (y0 - r * d - 5100000),
  };
}

test('bilinearAt is exact on a plane, with its slope; pixelOf inverts world()', () => {
  const r = planeRaster();
  for (const [x, y] of [[500123.4, 5099876.5], [500200, 5099800], [500010.01, 5099700.7]]) {
    const b = bilinearAt(r, x, y);
    assert.ok(Math.abs(b.h - (100 + 0.2 * (x - 500000) - 0.1 * (y - 5100000))) < 1e-9, `${x}, ${y}: ${b.h}`);
    assert.ok(Math.abs(b.slope - Math.hypot(0.2, 0.1)) < 1e-9);
    const [c, rr] = pixelOf(r, ...r.world(7, 9));
    assert.ok(Math.abs(c - 7) < 1e-12 && Math.abs(rr - 9) < 1e-12);
  }
  assert.ok(Number.isNaN(bilinearAt(r, 499990, 5099900).h), 'outside the raster: NaN');
});

test('fromLonLat inverts toLonLat, and agrees with PROJ (gdaltransform)', () => {
  const f = fromLonLat(32632), b = toLonLat(32632);
  const [x, y] = f(10.7, 46.6);
  const [lon, lat] = b(x, y);
  assert.ok(Math.abs(lon - 10.7) < 1e-10 && Math.abs(lat - 46.6) < 1e-10);
  let out;
  try {
    out = execFileSync('gdaltransform', ['-s_srs', 'EPSG:4326', '-t_srs', 'EPSG:32632', '-output_xy'], { input: '10.7 46.6\n', encoding: 'utf8' });
  } catch (err) {
    if (err.code === 'ENOENT') throw new Error('gdaltransform is missing (apt-get install -y gdal-bin)');
    throw err;
  }
  // (gdaltransform takes longitude, latitude: the traditional GIS order)
  const [gx, gy] = out.trim().split(/\s+/).map(Number);
  assert.ok(Math.abs(gx - x) < 1e-3 && Math.abs(gy - y) < 1e-3, `proj4js ${x}, ${y}; PROJ ${gx}, ${gy}`);
});

test('snapToSamples lands on zoom z sample positions; halfUvStep is half a u/v step', () => {
  for (const z of [0, 2, 11, 12]) {
    const s = sampleStep(z);
    const [lon, lat] = snapToSamples(10.4567, 46.789, z);
    assert.ok(Math.abs(lon - 10.4567) <= s / 2 + 1e-12 && Math.abs(lat - 46.789) <= s / 2 + 1e-12);
    const k = (lon + 180) / s;
    assert.ok(Math.abs(k - Math.round(k)) < 1e-6, `${z}: ${k}`);
  }
  // zoom 11: a tile is 180/2048°, half of its 1/32767 at the equator
  const [e, n] = halfUvStep(11, 0);
  assert.ok(Math.abs(n - (0.5 / 32767) * (180 / 2048) * (Math.PI / 180) * 6378137) < 1e-12 && Math.abs(e - n) < 1e-12);
});
