// Unit tests of the readers and geodesy the interop checks compute their expectations with
// (`node --test test/`): they must be right independently of terrastream. References: GDAL
// (gdalinfo, gdallocationinfo, run here) and PROJ figures recorded below with the command that
// gave them. Needs the shared data (TERRASTREAM_DATA, default ../../../shared/data), Debian's
// proj-data and gdal-bin.
import test from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { execFileSync } from 'node:child_process';
import { fileURLToPath } from 'node:url';
import { readGeoTiff, lzwDecode } from '../lib/geotiff.mjs';
import { readGtx, EGM96_GTX } from '../lib/geoid.mjs';
import { toLonLat, ecefOf, interiorGrid, placeSample } from '../lib/earth.mjs';
import { regionContains } from '../lib/heights.mjs';
import { f32Step } from '../lib/glb.mjs';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const DATA = process.env.TERRASTREAM_DATA ? path.resolve(process.env.TERRASTREAM_DATA) : path.resolve(HERE, '../../../../shared/data');
const GEO = path.join(DATA, 'geo');
const FILES = ['nad83_utm18n_dem.tif', 'utm32n_vinschgau.tif', 'utm32n_pixelispoint_n00e010.tif', 'etopo1_global_1deg.tif'];

function run(cmd, args, input) {
  try {
    return execFileSync(cmd, args, { input, encoding: 'utf8', stdio: ['pipe', 'pipe', 'pipe'] });
  } catch (err) {
    if (err.code === 'ENOENT') throw new Error(`${cmd} is missing: these tests compare with GDAL (apt-get install -y gdal-bin)`);
    throw err;
  }
}
const gdal = (cmd, args) => run(cmd, args);

test('GeoTIFF reader: every file of geo/ against GDAL (georeference, EPSG, values, no-data)', () => {
  for (const f of FILES) {
    const file = path.join(GEO, f);
    const r = readGeoTiff(file);
    const info = JSON.parse(gdal('gdalinfo', ['-json', file]));
    assert.deepEqual([r.width, r.height], info.size, f);
    // GDAL's geotransform is the corner of pixel (0, 0) for PixelIsArea and PixelIsPoint alike;
    // a sample's centre is half a cell in
    const gt = info.geoTransform;
    for (const [col, row] of [[0, 0], [r.width - 1, 0], [7, r.height - 1], [r.width >> 1, r.height >> 1]]) {
      const [x, y] = r.world(col, row);
      assert.ok(Math.abs(x - (gt[0] + (col + 0.5) * gt[1])) < 1e-6 && Math.abs(y - (gt[3] + (row + 0.5) * gt[5])) < 1e-6, `${f} (${col}, ${row}): ${x}, ${y}`);
    }
    const epsg = Number(/ID\["EPSG",(\d+)\]\]\s*$/.exec(info.coordinateSystem.wkt)[1]);
    assert.equal(r.epsg, epsg, f);
    assert.equal(r.pixelIsPoint, info.metadata?.['']?.AREA_OR_POINT === 'Point', f);
    // values at 40 pseudo-random pixels, and every no-data pixel of a row, through gdallocationinfo
    let seed = 7;
    const rnd = (n) => (seed = (seed * 1103515245 + 12345) % 2 ** 31) % n;
    const pts = Array.from({ length: 40 }, () => [rnd(r.width), rnd(r.height)]);
    const out = run('gdallocationinfo', ['-valonly', file], pts.map((p) => p.join(' ')).join('\n')).trim().split('\n');
    const nodata = info.bands[0].noDataValue;
    pts.forEach(([c, rr], i) => {
      const v = Number(out[i]);
      if (nodata !== undefined && (v === nodata || Math.abs(v - nodata) <= Math.abs(nodata) * 1e-6)) assert.ok(Number.isNaN(r.at(c, rr)), `${f} (${c}, ${rr}) is no-data`);
      // (gdallocationinfo prints 15 significant digits)
      else assert.ok(Math.abs(r.at(c, rr) - v) <= 1e-12 * Math.max(1, Math.abs(v)), `${f} (${c}, ${rr}): ${r.at(c, rr)} vs GDAL ${v}`);
    });
  }
});

test('GeoTIFF reader: LZW strips decode to what GDAL reads, row by row (Vinschgau, float32 no-data)', () => {
  const file = path.join(GEO, 'utm32n_vinschgau.tif');
  const r = readGeoTiff(file);
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'interop-test-'));
  try {
    // the whole raster as XYZ text by GDAL: x y value per sample, rows from the top
    gdal('gdal_translate', ['-q', '-of', 'XYZ', file, path.join(tmp, 'v.xyz')]);
    const lines = fs.readFileSync(path.join(tmp, 'v.xyz'), 'utf8').trim().split('\n');
    assert.equal(lines.length, r.width * r.height);
    let nodata = 0;
    lines.forEach((line, i) => {
      const v = Number(line.trim().split(/\s+/)[2]);
      const mine = r.at(i % r.width, Math.floor(i / r.width));
      if (v < -1e38) {
        nodata++;
        assert.ok(Number.isNaN(mine), `sample ${i}`);
      } else assert.ok(Math.abs(mine - v) <= 1e-12 * Math.max(1, Math.abs(v)), `sample ${i}: ${mine} vs GDAL ${v}`);
    });
    assert.ok(nodata > 0, 'the Vinschgau DEM has no-data cells (445 by GDAL)');
  } finally {
    fs.rmSync(tmp, { recursive: true, force: true });
  }
});

test('LZW: a hand-made stream (clear, literals, a code defined by its own use, end) and malformed ones', () => {
  // codes (9 bits): 256 clear, 65 'A', 258 (= 'AA', the KwKwK case), 66 'B', 257 end
  const codes = [256, 65, 258, 66, 257];
  let bits = '';
  for (const c of codes) bits += c.toString(2).padStart(9, '0');
  bits = bits.padEnd(Math.ceil(bits.length / 8) * 8, '0');
  const bytes = Uint8Array.from(bits.match(/.{8}/g).map((b) => parseInt(b, 2)));
  assert.deepEqual(Array.from(lzwDecode(bytes)), [65, 65, 65, 66]);
  // a code beyond the table
  let bad = '';
  for (const c of [256, 65, 300, 257]) bad += c.toString(2).padStart(9, '0');
  bad = bad.padEnd(Math.ceil(bad.length / 8) * 8, '0');
  assert.throws(() => lzwDecode(Uint8Array.from(bad.match(/.{8}/g).map((b) => parseInt(b, 2)))), /beyond the table/);
});

test('GeoTIFF reader: a file that is not a TIFF is refused by name', () => {
  const tmp = path.join(os.tmpdir(), `interop-not-a-tiff-${process.pid}.tif`);
  fs.writeFileSync(tmp, 'PK\x03\x04 not a tiff at all');
  try {
    assert.throws(() => readGeoTiff(tmp), /not a TIFF/);
  } finally {
    fs.rmSync(tmp, { force: true });
  }
});

test('EGM96 GTX: grid nodes as GDAL reads them, bilinear and the antimeridian as PROJ does', () => {
  const g = readGtx(EGM96_GTX);
  assert.deepEqual([g.lat0, g.lon0, g.dlat, g.dlon, g.rows, g.cols], [-90, -180, 0.25, 0.25, 721, 1440]);
  // nodes: GDAL's GTX driver puts each node at a pixel centre
  const nodes = [[10.5, 0.5], [-179.75, -60], [179.75, 60.25], [138.75, 35.25], [-73, 44], [0, 89.75]];
  const out = run('gdallocationinfo', ['-valonly', '-geoloc', EGM96_GTX], nodes.map((p) => p.join(' ')).join('\n')).trim().split('\n');
  nodes.forEach(([lon, lat], i) => assert.ok(Math.abs(g.undulation(lon, lat) - Number(out[i])) < 1e-4, `node ${lon}, ${lat}: ${g.undulation(lon, lat)} vs GDAL ${out[i]}`));
  // between nodes, PROJ 9.5 (pyproj 3.7) with
  //   Transformer.from_pipeline('+proj=vgridshift +grids=/usr/share/proj/egm96_15.gtx +multiplier=1')
  const proj = [
    [10.55, 0.53, 10.391481834411632], [-179.93, -60.1, -46.4369691772461], [179.93, -60.1, -46.44746170043945],
    [180, 0, 21.153329849243164], [-180, 0, 21.153329849243164], [138.7274, 35.3606, 41.2509509697705],
    [-72.81, 44.12, -28.518884405517582], [0, 89.9, 13.724816513061517], [45.3, -89.95, -29.56072128295898],
    [359.9, 10.1, 23.422859268188468],
  ];
  for (const [lon, lat, n] of proj) assert.ok(Math.abs(g.undulation(lon, lat) - n) < 1e-6, `${lon}, ${lat}: ${g.undulation(lon, lat)} vs PROJ ${n}`);
  assert.throws(() => g.undulation(0, 91), /outside the grid/);
});

test('EGM96 GTX: a truncated file is refused', () => {
  const tmp = path.join(os.tmpdir(), `interop-short-${process.pid}.gtx`);
  fs.writeFileSync(tmp, fs.readFileSync(EGM96_GTX).subarray(0, 1000));
  try {
    assert.throws(() => readGtx(tmp), /a 721×1440 GTX grid has/);
  } finally {
    fs.rmSync(tmp, { force: true });
  }
});

test('proj4js with the EPSG definitions of lib/earth.mjs agrees with PROJ and GDAL', () => {
  // PROJ 9.5 (pyproj 3.7): Transformer.from_crs(code, 4326, always_xy=True).transform(x, y)
  const proj = [
    [26918, 664737, 4895779, -72.93845191766624, 44.19663012233044],
    [26918, 685977, 4878949, -72.67879331046805, 44.04012491456572],
    [32632, 611263.658620015, 110597.858, 9.999998758083374, 1.0004591005884462],
    [32632, 722579.65, 21.5, 10.999858189199253, 0.0001943979678872481],
    [32632, 598375, 5192875, 10.29114275955314, 46.88213053454193],
  ];
  for (const [code, x, y, lon, lat] of proj) {
    const [l, b] = toLonLat(code)(x, y);
    // 1e-8° is a millimetre
    assert.ok(Math.abs(l - lon) < 1e-8 && Math.abs(b - lat) < 1e-8, `EPSG:${code} ${x}, ${y}: ${l}, ${b} vs PROJ ${lon}, ${lat}`);
  }
  // and GDAL (gdaltransform) at each file's centre
  for (const f of FILES.slice(0, 3)) {
    const r = readGeoTiff(path.join(GEO, f));
    const [x, y] = r.world(r.width >> 1, r.height >> 1);
    const [lon, lat] = run('gdaltransform', ['-s_srs', `EPSG:${r.epsg}`, '-t_srs', 'EPSG:4326'], `${x} ${y}\n`).trim().split(/\s+/).map(Number);
    // gdaltransform prints EPSG:4326 as latitude, longitude (its axis order) or the reverse: either
    const [l, b] = toLonLat(r.epsg)(x, y);
    const ok = (Math.abs(l - lon) < 1e-7 && Math.abs(b - lat) < 1e-7) || (Math.abs(l - lat) < 1e-7 && Math.abs(b - lon) < 1e-7);
    assert.ok(ok, `${f}: ${l}, ${b} vs GDAL ${lon}, ${lat}`);
  }
  assert.throws(() => toLonLat(2056), /EPSG:2056 is not among/);
});

test('ECEF of WGS 84 points', () => {
  const b = 6378137 * (1 - 1 / 298.257223563);
  const near = (p, q) => p.every((v, i) => Math.abs(v - q[i]) < 1e-6);
  assert.ok(near(ecefOf(0, 0, 0), [6378137, 0, 0]));
  assert.ok(near(ecefOf(90, 0, 10), [0, 6378147, 0]));
  assert.ok(near(ecefOf(-180, 0, 0), [-6378137, 0, 0]));
  assert.ok(near(ecefOf(0, 90, 0), [0, 0, b]));
  assert.ok(near(ecefOf(123, -90, 5), [0, 0, -b - 5]));
});

test('sample grid: interior, moved off no-data, an error when there is none', () => {
  const holes = new Set(['5,5', '6,5', '5,6']);
  const raster = { width: 20, height: 12, at: (c, r) => (holes.has(`${c},${r}`) ? NaN : c + r), world: (c, r) => [c, r] };
  const grid = interiorGrid(raster, 4);
  assert.equal(grid.length, 16);
  for (const g of grid) {
    assert.ok(g.col >= 1 && g.col <= 18 && g.row >= 1 && g.row <= 10);
    for (let dr = -1; dr <= 1; dr++) for (let dc = -1; dc <= 1; dc++) assert.ok(!holes.has(`${g.col + dc},${g.row + dr}`), `${g.col}, ${g.row} is next to no-data`);
  }
  assert.ok(grid.some((g) => g.moved > 0), 'the grid point (5, 5) moves');
  const empty = { width: 20, height: 12, at: () => NaN, world: (c, r) => [c, r] };
  assert.throws(() => interiorGrid(empty, 4), /no sample with data/);
  const s = placeSample(raster, (x, y) => [x, y], { undulation: () => 2.5 }, 3, 4);
  assert.deepEqual([s.value, s.undulation, s.h], [7, 2.5, 9.5]);
});

test('regions: containment across the antimeridian and at the poles', () => {
  const d = Math.PI / 180;
  assert.ok(regionContains([170 * d, -10 * d, -170 * d, 10 * d, 0, 1], 179.5, 0));
  assert.ok(regionContains([170 * d, -10 * d, -170 * d, 10 * d, 0, 1], -175, 5));
  assert.ok(!regionContains([170 * d, -10 * d, -170 * d, 10 * d, 0, 1], 0, 0));
  assert.ok(!regionContains([10 * d, -10 * d, 20 * d, 10 * d, 0, 1], 15, 11));
  assert.ok(regionContains([-Math.PI, 80 * d, Math.PI, 90 * d, 0, 1], 123, 90));
});

test('f32 step: the float spacing at the largest coordinate; FLOAT positions only', () => {
  const gltf = (min, max, componentType = 5126) => ({ nodes: [{ mesh: 0 }], meshes: [{ primitives: [{ attributes: { POSITION: 0 } }] }], accessors: [{ componentType, min, max }] });
  assert.equal(f32Step(gltf([-1000, 0, -3], [1024, 5, 2])).step, 2 ** -13);   // 1024 = 2^10: ulp 2^-13
  assert.equal(f32Step(gltf([-1023.9, 0, 0], [1, 1, 1])).step, 2 ** -14);
  assert.equal(Math.fround(1024 + 2 ** -13), 1024 + 2 ** -13);
  assert.notEqual(Math.fround(1024 + 2 ** -15), 1024 + 2 ** -15);
  assert.throws(() => f32Step(gltf([0, 0, 0], [1, 1, 1], 5123)), /not FLOAT/);
});
