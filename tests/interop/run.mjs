#!/usr/bin/env node
// Interoperability checks of terrastream's 3D Tiles output: bake fuji + bunny and the four real
// DEMs of geo/ (placed exactly on the Earth), serve them, then walk, validate (Khronos), parse
// (loaders.gl), render (CesiumJS, offline), compare CesiumJS's heights with heights computed from
// the source rasters alone (proj4js, the EGM96 grid), and open the server's own viewer; check
// that it shows the relief of a real DEM (SRTM, UTM 32N) and of fuji below sea level. The DEMs'
// Cesium globe terrain (quantized-mesh-1.0, baked with --terrain, and one served on demand): every
// tile decoded by @here/quantized-mesh-decoder and checked, a crack test on neighbours, on-demand
// tiles against baked ones, CesiumJS (the docs example page: a flight, sampleTerrainMostDetailed
// against the source rasters) and 3DTilesRendererJS's QuantizedMeshPlugin; the same terrain as 3D
// Tiles (every GLB and subtree against the quantized-mesh tiles, the glTF validator, CesiumJS's
// Cesium3DTilesTerrainProvider against its quantized-mesh provider). The last line printed
// is `N passed, N failed`; exit 1 on a failure.
//
// Environment: TERRASTREAM_BIN, TERRASTREAM_DATA, CHROMIUM, INTEROP_OUT (see README.md),
// INTEROP_TIMEOUT_S (whole run, default 660), INTEROP_KEEP=1 (keep the temp store).
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { Checks, CheckFailure } from './lib/checks.mjs';
import { runCommand, startDaemon, stopDaemon, freePort, waitReady, killAllChildren, fetchWithTimeout } from './lib/proc.mjs';
import { walkTileset, truncate } from './lib/walk.mjs';
import { validateGlbs } from './lib/validate.mjs';
import { loadersGlCheck } from './lib/loadersgl.mjs';
import { startStaticServer } from './lib/static-server.mjs';
import { launchBrowser } from './lib/browser.mjs';
import { cesiumLoadCheck, heightsCheck, earthHeightsCheck } from './lib/cesium.mjs';
import { viewerCheck, reliefCheck, seaLevelCheck } from './lib/viewer.mjs';
import { readTerrainRgb, checkPlacement, localFrame, toLocal } from './lib/heights.mjs';
import { readGeoTiff } from './lib/geotiff.mjs';
import { readGtx, EGM96_GTX } from './lib/geoid.mjs';
import { toLonLat, placeSample, interiorGrid } from './lib/earth.mjs';
import { multiplyPoint } from './lib/mat4.mjs';
import { terrainSamples, closeHttp } from './lib/terrain.mjs';
import { decodeCheck, crackCheck, onDemandCheck, cesiumTerrainCheck, terrainHeightsCheck, threeTerrainCheck } from './lib/qm-checks.mjs';
import { tiles3dTerrainCheck, cesium3dTerrainCheck } from './lib/t3d-checks.mjs';
import { maplibreCheck } from './lib/maplibre.mjs';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const fromHere = (p) => path.resolve(HERE, p);
const cfg = {
  bin: process.env.TERRASTREAM_BIN ? path.resolve(process.env.TERRASTREAM_BIN) : fromHere('../../target/release/terrastream'),
  data: process.env.TERRASTREAM_DATA ? path.resolve(process.env.TERRASTREAM_DATA) : fromHere('../../../shared/data'),
  chromium: process.env.CHROMIUM || '/usr/bin/chromium',
  out: process.env.INTEROP_OUT ? path.resolve(process.env.INTEROP_OUT) : fromHere('out'),
  timeoutS: Number(process.env.INTEROP_TIMEOUT_S || 660),
  keep: process.env.INTEROP_KEEP === '1',
};

// The fuji bake: a 512×512 terrain-RGB PNG, 30 m cells, origin 0, anchored at Mt. Fuji, in
// 32-cell tiles: a quadtree 4 deep, so the root's children are external tilesets (one per index
// chunk below the root) and every client must follow them.
const FUJI = { cellSize: 30, tileSize: 32, anchor: { lon: 138.7274, lat: 35.3606 } };
const MIN_SHARE = { fuji: 0.1, bunny: 0.02 };
// The real DEMs of geo/ (see its README), each with a CRS, so placed exactly on the Earth. Small
// leaf tiles and one point level keep the bakes and CesiumJS quick on two cores. SRTM-derived
// heights (the Gabon tile, ETOPO1) are orthometric: baked with --vertical-datum egm96, and their
// expected heights add the EGM96 undulation. `rows`/`cols`: the sample grid's span when it is not
// the raster's interior (see HEIGHTS_GRID).
const GEO = [
  { name: 'gabon', file: 'geo/utm32n_pixelispoint_n00e010.tif', egm96: true, tileSize: 128 },
  { name: 'nad83', file: 'geo/nad83_utm18n_dem.tif', egm96: false, tileSize: 32 },
  { name: 'vinschgau', file: 'geo/utm32n_vinschgau.tif', egm96: false, tileSize: 32 },
  { name: 'etopo', file: 'geo/etopo1_global_1deg.tif', egm96: true, tileSize: 32 },
];
const TILESETS = ['fuji', 'bunny', ...GEO.map((g) => g.name)];
// Check e on the Earth: a k×k grid of raster samples (not the outer 2 on any side), each within
// its tile's errors.max + HEIGHTS_MARGIN m + its GLB's f32 step.
const HEIGHTS_GRID = 6;
const HEIGHTS_MARGIN = 0.1;
// Check g, the viewer's relief on a real DEM: the Gabon tile of GEO (SRTM-derived, UTM 32N,
// PixelIsPoint, the coast at the equator, heights 1–1005 m, a low coastal plain in the west). Its
// centre as GDAL puts it (`gdalinfo`: 10°29'59.78"E, 0°30'0.93"N), for the server's globe position.
const RELIEF = {
  name: 'gabon',
  globe: { crs: 'EPSG:32632', vertical_datum: 'egm96', lon: 10 + 29 / 60 + 59.78 / 3600, lat: 30 / 60 + 0.93 / 3600, tolerance: 0.01, from: 'gdalinfo' },
  exaggeration: 5,
};
// And sea level: fuji lowered by 1000 m, so its heights run from about −986 m to 2751 m; and the
// whole globe (ETOPO1 of GEO: oceans and land, EGM96 heights), seen from space.
const SEA = { name: 'fuji-sea', zOffset: -1000 };
const GLOBE_SEA = 'etopo';
const GLOBE_SEA_SSE = 2;
// Globe terrain (checks h–j): every GEO DEM is baked with --terrain (default error scale and
// zooms, as the server's on-demand terrain). TERRAIN_LIVE serves the vinschgau DEM again as an
// on-demand --source tileset, whose tiles must be the baked ones byte for byte.
const TERRAIN_LIVE = { name: 'vinschgau-live', baked: 'vinschgau' };
// MapLibre GL JS on the heightmap tiles of this tileset: a tilted view over the data's centre.
const MAPLIBRE = { name: 'vinschgau', zoom: 11, pitch: 50 };
// CesiumJS on the docs example page: a flight onto each of these, then sampleTerrainMostDetailed
// on a TERRAIN_GRID² grid. Regional DEMs: from 15,000 km straight down to 15 km at 35° over the
// data's centre. ETOPO1: the globe, the antimeridian (Fiji) and both poles. The page as users get
// it (Natural Earth II imagery) on vinschgau; without imagery (&imagery=none) on the others, and
// 640×480: SwiftShader draws a frame or two a second.
const TERRAIN_CESIUM = [{ name: 'vinschgau', imagery: true }, { name: 'gabon', imagery: false }, { name: 'etopo', imagery: false }];
const TERRAIN_GRID = 6;
const TERRAIN_MS_PER_STOP = 30_000;
const TERRAIN_VIEWPORT = { width: 640, height: 480 };
const REGIONAL_STOPS = [
  { range: 1.5e7, pitch: -90 },
  { range: 1.5e6, pitch: -90 },
  { range: 2e5, pitch: -60 },
  { range: 5e4, pitch: -45 },
  { range: 1.5e4, pitch: -35 },
];
const GLOBE_STOPS = [
  { lon: 10, lat: 20, h: 0, range: 2.2e7, pitch: -90 },
  { lon: 180, lat: 0, h: 0, range: 8e6, pitch: -90 },
  { lon: 179, lat: -17, h: 0, range: 2e6, pitch: -60 },
  { lon: 0, lat: 89.9, h: 0, range: 6e6, pitch: -90 },
  { lon: 0, lat: -89.9, h: 2800, range: 6e6, pitch: -90 },
];
// 3DTilesRendererJS (check j): looking down on the vinschgau terrain from 30 km, it must refine
// to zoom 9 at least (its tiles' geometric error 77,067 m / 2^z against its errorTarget of 2 px
// asks for zoom 10 at 1024×768 from there).
const THREE_TERRAIN = { name: 'vinschgau', range: 3e4, minZoom: 9 };
// The terrain as 3D Tiles (check k): every tile of vinschgau's (and the on-demand copy's) and of
// etopo's (the antimeridian, the poles, hemisphere-sized tiles), then CesiumJS's
// Cesium3DTilesTerrainProvider flying over each (no imagery, 640×480; vinschgau three stops of
// check i's, etopo check i's globe stops) and sampleTerrainMostDetailed from both providers at a
// grid² of points on the deepest zoom's sample lattice and as many a third of a cell off it
// (inside triangles). Height tolerance: the GLB stores each vertex as an f32 offset from the
// tile's centre, so two f32 steps of a deepest-zoom tile's size (2⁻²² × π·6,378,137 m / 2^z:
// 2 mm at vinschgau's zoom 11, 1.2 m at etopo's zoom 2; CesiumJS keeps heights and u/v in f32
// too), at least 5 mm. Pictures: the last stop drawn with the quantized-mesh provider must match
// (≤ 0.1 % of the pixels off by more than 16 of 255).
const T3D = [
  { name: 'vinschgau', live: TERRAIN_LIVE.name, grid: 5, stops: REGIONAL_STOPS.slice(1, 2).concat(REGIONAL_STOPS.slice(3)) },
  // (heights compared up to 85° of latitude: nearer a pole CesiumJS's 3D Tiles terrain scrambles
  // the u of the triangles fanning from the pole vertex, whose longitude it cannot recover;
  // reported in the details)
  { name: 'etopo', live: null, grid: 3, stops: GLOBE_STOPS, poleZoneDeg: 85 },
];
const T3D_MS_PER_STOP = 30_000;
const T3D_MAX_DIFF_SHARE = 0.001;
// The example page for users; check i opens it with its CesiumJS CDN URL pointed at the local copy.
const EXAMPLE = { file: '../../docs/examples/cesium-terrain.html', cdn: 'https://cesium.com/downloads/cesiumjs/releases/1.140/Build/Cesium/' };

const checks = new Checks();
const runStarted = Date.now();
const cleanups = [];
let finished = false;

async function cleanup() {
  while (cleanups.length) {
    const fn = cleanups.pop();
    try {
      await fn();
    } catch (err) {
      console.log(`cleanup: ${err.message}`);
    }
  }
  killAllChildren();
}

function finish(code) {
  if (finished) return;
  finished = true;
  console.log(checks.summary());
  console.log(`run took ${((Date.now() - runStarted) / 1000).toFixed(1)} s`);
  console.log(`${checks.passed} passed, ${checks.failed} failed`);
  process.exitCode = code ?? (checks.failed > 0 ? 1 : 0);
}

// Whatever happens, nothing outlives the run: a hard timeout, signals, and exit all clean up.
const hardTimer = setTimeout(async () => {
  checks.fail('run', `hard timeout: the whole run took longer than ${cfg.timeoutS} s; stopped`);
  const force = setTimeout(() => {
    killAllChildren();
    finish(1);
    process.exit(1);
  }, 15_000);
  force.unref();
  await cleanup();
  finish(1);
  process.exit(1);
}, cfg.timeoutS * 1000);
hardTimer.unref();
for (const sig of ['SIGINT', 'SIGTERM']) {
  process.on(sig, async () => {
    checks.fail('run', `interrupted by ${sig}`);
    await cleanup();
    finish(1);
    process.exit(1);
  });
}
process.on('exit', () => killAllChildren());

/** A check that needs an earlier step: fails with the reason when that step did not happen. */
function needs(cond, reason) {
  if (!cond) throw new CheckFailure(`not run: ${reason}`);
}

async function main() {
  console.log(`terrastream interop: bin ${cfg.bin}, data ${cfg.data}, chromium ${cfg.chromium}, out ${cfg.out}`);
  fs.mkdirSync(cfg.out, { recursive: true });
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'terrastream-interop-'));
  const store = path.join(tmp, 'store');
  fs.mkdirSync(store);
  cleanups.push(() => {
    if (cfg.keep) console.log(`kept ${tmp}`);
    else fs.rmSync(tmp, { recursive: true, force: true });
  });

  // 1. bake
  const baked = {};
  const bakes = {
    fuji: ['bake', path.join(cfg.data, 'fuji.png'), '--encoding', 'terrain-rgb', '--cell-size', String(FUJI.cellSize), '--tile-size', String(FUJI.tileSize), '--anchor', `${FUJI.anchor.lon},${FUJI.anchor.lat}`, '--gpu', 'off', '--out', path.join(store, 'fuji')],
    bunny: ['bake-model', path.join(cfg.data, 'stanford-bunny.obj'), '--gpu', 'off', '--out', path.join(store, 'bunny')],
    [SEA.name]: ['bake', path.join(cfg.data, 'fuji.png'), '--encoding', 'terrain-rgb', '--cell-size', String(FUJI.cellSize), '--z-offset', String(SEA.zOffset), '--gpu', 'off', '--out', path.join(store, SEA.name)],
  };
  for (const g of GEO) {
    bakes[g.name] = ['bake', path.join(cfg.data, g.file), '--tile-size', String(g.tileSize), '--levels', '1', ...(g.egm96 ? ['--vertical-datum', 'egm96'] : []), '--terrain', '--gpu', 'off', '--out', path.join(store, g.name)];
  }
  for (const name of Object.keys(bakes)) {
    baked[name] = await checks.run(`bake ${name}`, async (log) => {
      if (!fs.existsSync(cfg.bin)) throw new CheckFailure(`no binary at ${cfg.bin} (set TERRASTREAM_BIN)`);
      log(`$ ${path.basename(cfg.bin)} ${bakes[name].join(' ')}`);
      const r = await runCommand(cfg.bin, bakes[name], { timeoutMs: 180_000 });
      if (r.timedOut) throw new CheckFailure(`killed after 180 s`, r.stderr.split('\n').slice(-20));
      if (r.code !== 0) {
        const output = (r.stderr.trim() || r.stdout.trim() || '(no output)').split('\n');
        throw new CheckFailure(`exit ${r.code ?? r.signal}: ${truncate(output.slice(-3).join(' | '), 600)}`, output.slice(-30));
      }
      return `baked in ${(r.ms / 1000).toFixed(1)} s`;
    });
  }

  // 2. serve
  const port = await freePort();
  const base = `http://127.0.0.1:${port}`;
  const served = await checks.run('serve', async (log) => {
    needs(fs.existsSync(cfg.bin), `no binary at ${cfg.bin}`);
    const live = GEO.find((g) => g.name === TERRAIN_LIVE.baked);
    // (vinschgau's heights are ellipsoidal as they are: --source has no vertical datum key)
    const sourceArgs = ['--source', `${TERRAIN_LIVE.name}=${path.join(cfg.data, live.file)}`];
    const daemon = startDaemon(cfg.bin, ['serve', '--store', store, '--bind', `127.0.0.1:${port}`, '--gpu', 'off', ...sourceArgs]);
    cleanups.push(() => closeHttp());
    cleanups.push(async () => {
      await stopDaemon(daemon);
      const output = daemon.output.trim();
      if (checks.failed > 0 && output) console.log(`--- server output (last lines)\n${output.split('\n').slice(-40).join('\n')}`);
    });
    await waitReady(`${base}/readyz`, daemon, 60_000);
    const r = await fetchWithTimeout(`${base}/readyz`);
    log(`GET /readyz -> ${r.status} ${truncate(await r.text(), 200)}`);
    return `ready on ${base}`;
  });

  // 3a-c. walk, validate, parse
  const walks = {};
  for (const name of TILESETS) {
    const url = `${base}/tilesets/${name}/3dtiles/tileset.json`;
    await checks.run(`a. walk ${name}`, async (log) => {
      needs(served, 'the server is not running');
      if (!baked[name]) log(`note: the bake of ${name} failed`);
      const w = await walkTileset(url);
      walks[name] = w;
      const external = w.jsons.length - (w.rootJson ? 1 : 0);
      const bytes = w.glbs.reduce((s, g) => s + g.buf.length, 0);
      const depth = w.tiles.reduce((m, t) => Math.max(m, t.depth), 0);
      for (const n of w.notes) log(`note: ${n}`);
      const msg = `${w.jsons.length} tileset JSONs (${external} external), ${w.tiles.length} tiles, depth ${depth}, ${w.glbs.length} GLBs (${(bytes / 1024).toFixed(0)} KiB), ${w.fetches} fetches`;
      if (w.errors.length) throw new CheckFailure(`${w.errors.length} problem(s), first: ${truncate(w.errors[0], 300)}; ${msg}`, w.errors);
      if (w.glbs.length === 0) throw new CheckFailure(`no GLB content found; ${msg}`);
      return msg;
    });
  }
  for (const name of TILESETS) {
    await checks.run(`b. gltf-validator ${name}`, async (log) => {
      needs(walks[name], 'no walk');
      return validateGlbs(walks[name].glbs, log);
    });
  }
  for (const name of TILESETS) {
    await checks.run(`c. loaders.gl ${name}`, async (log) => {
      needs(walks[name], 'no walk');
      return loadersGlCheck(walks[name], log);
    });
  }
  await checks.run('placement fuji', async (log) => {
    needs(walks.fuji?.rootJson, 'no fuji tileset.json');
    let lf;
    try {
      lf = localFrame(walks.fuji.rootJson);
    } catch (err) {
      throw new CheckFailure(err.message);
    }
    const raster = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
    // the centre of the samples' extent, at height 0
    const centre = toLocal(lf, ((raster.width - 1) * FUJI.cellSize) / 2, ((raster.height - 1) * FUJI.cellSize) / 2, 0);
    log(`local_frame: origin [${lf.origin.join(', ')}], north ${lf.north}`);
    const { lines, problems } = checkPlacement(walks.fuji.rootJson, FUJI.anchor, centre);
    lines.forEach(log);
    if (problems.length) throw new CheckFailure(problems[0], problems);
    return 'root.transform is east-north-up, the centre of the data at height 0 sits on the anchor';
  });

  // h. globe terrain: every tile decoded and checked, cracks, on demand = baked
  const terrain = {};
  for (const g of GEO) {
    await checks.run(`h. terrain decode ${g.name}`, async (log) => {
      needs(served, 'the server is not running');
      if (!baked[g.name]) log(`note: the bake of ${g.name} failed`);
      const out = {};
      try {
        return await decodeCheck({ base, name: g.name, out, log });
      } finally {
        if (out.tiles) terrain[g.name] = out;
      }
    });
    await checks.run(`h. terrain cracks ${g.name}`, async (log) => {
      needs(terrain[g.name]?.tiles?.size, `no decoded tiles of ${g.name}`);
      return crackCheck({ tiles: terrain[g.name].tiles, log });
    });
  }
  await checks.run(`h. terrain on demand = baked ${TERRAIN_LIVE.baked}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[TERRAIN_LIVE.baked], `the bake of ${TERRAIN_LIVE.baked} failed`);
    return onDemandCheck({ base, baked: TERRAIN_LIVE.baked, live: TERRAIN_LIVE.name, log });
  });

  // the example page with CesiumJS from here rather than its CDN (checks i run it offline)
  const exampleDir = path.join(tmp, 'example');
  fs.mkdirSync(exampleDir, { recursive: true });
  let exampleError = null;
  try {
    const example = fs.readFileSync(fromHere(EXAMPLE.file), 'utf8');
    if (!example.includes(EXAMPLE.cdn)) throw new Error(`${EXAMPLE.file} does not load CesiumJS from ${EXAMPLE.cdn}`);
    fs.writeFileSync(path.join(exampleDir, path.basename(EXAMPLE.file)), example.split(EXAMPLE.cdn).join('/cesium/'));
  } catch (err) {
    exampleError = err.message;
  }

  // 3d-f. browsers
  let browser = null;
  let pageBase = null;
  let browserError = null;
  try {
    const cesiumDir = fromHere('node_modules/cesium/Build/Cesium');
    if (!fs.existsSync(path.join(cesiumDir, 'Cesium.js'))) throw new Error(`${cesiumDir}/Cesium.js is missing (npm ci?)`);
    const st = await startStaticServer({
      '/cesium/': cesiumDir,
      '/example/': exampleDir,
      '/three/': fromHere('node_modules/three'),
      '/3d-tiles-renderer/': fromHere('node_modules/3d-tiles-renderer'),
      '/maplibre-gl/': fromHere('node_modules/maplibre-gl/dist'),
      '/': fromHere('page'),
    });
    cleanups.push(() => new Promise((r) => {
      st.server.close(r);
      st.server.closeAllConnections();
    }));
    pageBase = st.url;
    browser = await launchBrowser(cfg.chromium);
    cleanups.push(async () => {
      const proc = browser.process();
      let timer;
      await Promise.race([browser.close(), new Promise((r) => (timer = setTimeout(r, 10_000)))]).catch(() => {});
      clearTimeout(timer);
      if (proc && proc.exitCode === null) proc.kill('SIGKILL');
      for (const s of [proc?.stdin, proc?.stdout, proc?.stderr]) s?.destroy();
    });
    console.log(`chromium ${await browser.version()}; test page on ${pageBase}`);
  } catch (err) {
    browserError = err.message;
    if (!fs.existsSync(cfg.chromium)) browserError += ` (no ${cfg.chromium}: apt-get install -y chromium, or set CHROMIUM)`;
  }

  for (const name of TILESETS) {
    const session = {};
    await checks.run(`d. cesium ${name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      return cesiumLoadCheck({
        browser, pageUrl: `${pageBase}/index.html`, tilesetUrl: `${base}/tilesets/${name}/3dtiles/tileset.json`,
        screenshot: path.join(cfg.out, `cesium-${name}.png`), timeoutMs: 120_000, log, session,
      });
    });
    if (name === 'fuji') {
      await checks.run('e. heights fuji', async (log) => {
        needs(walks.fuji, 'no walk of fuji');
        const raster = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
        return heightsCheck({ session, walk: walks.fuji, raster, cellSize: FUJI.cellSize, grid: 6, timeoutMs: 90_000, log });
      });
    }
    const geo = GEO.find((g) => g.name === name);
    if (geo) {
      await checks.run(`e. heights ${name}`, async (log) => {
        needs(walks[name], `no walk of ${name}`);
        const { samples, lines } = expectedSamples(geo);
        lines.forEach(log);
        return earthHeightsCheck({ session, walk: walks[name], samples, margin: HEIGHTS_MARGIN, timeoutMs: 90_000, log });
      });
    }
    if (session.rec) fs.writeFileSync(path.join(cfg.out, `cesium-${name}-requests.txt`), `${session.rec.requests.join('\n')}\n`);
    if (session.page) await session.page.close().catch(() => {});
  }

  // The fuji tileset with compressed GLBs: `?glb=meshopt` (EXT_meshopt_compression) and
  // `?glb=draco` (KHR_draco_mesh_compression for the meshes, EXT_meshopt_compression for the
  // points) on the tileset JSON are carried into every URI it lists, and CesiumJS decodes both
  // extensions itself (Draco with its bundled decoder, ThirdParty/draco_decoder.wasm, in a worker).
  // Gabon is placed on the Earth: its GLBs have FLOAT positions in each node's east-north-up
  // frame, which Draco quantizes (24 bits over the primitive's extent).
  for (const [name, glb] of [['fuji', 'meshopt'], ['fuji', 'draco'], ['gabon', 'draco']]) {
    const session = {};
    await checks.run(`d. cesium ${name} ?glb=${glb}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      const said = await cesiumLoadCheck({
        browser, pageUrl: `${pageBase}/index.html`, tilesetUrl: `${base}/tilesets/${name}/3dtiles/tileset.json?glb=${glb}`,
        screenshot: path.join(cfg.out, `cesium-${name}-${glb}.png`), timeoutMs: 120_000, log, session,
      });
      const glbs = session.result.loaded.filter((u) => new URL(u, base).pathname.endsWith('.glb'));
      const plain = glbs.filter((u) => new URL(u, base).searchParams.get('glb') !== glb);
      if (plain.length) throw new CheckFailure(`${plain.length} of ${glbs.length} GLBs loaded without glb=${glb}, e.g. ${plain[0]}`);
      const got = session.rec.requests.filter((u) => u.includes('.glb') && u.includes(`glb=${glb}`)).length;
      // CesiumJS fetches its Draco decoder only when a glTF asks for it: proof it decoded one
      const decoder = session.rec.requests.filter((u) => /\/ThirdParty\/draco_decoder\.(wasm|js)$/.test(new URL(u, base).pathname));
      if (glb === 'draco' && decoder.length === 0) throw new CheckFailure(`CesiumJS never fetched ThirdParty/draco_decoder.wasm: no Draco mesh decoded (${glbs.length} GLBs loaded)`);
      return `${said}; all ${glbs.length} GLBs with glb=${glb} (${got} such requests)${glb === 'draco' ? `; CesiumJS's Draco decoder fetched (${decoder.map((u) => path.basename(new URL(u, base).pathname)).join(', ')})` : ''}`;
    });
    if (session.page) await session.page.close().catch(() => {});
  }

  for (const name of Object.keys(MIN_SHARE)) {
    await checks.run(`f. viewer ${name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      return viewerCheck({ browser, url: `${base}/viewer?tileset=${name}`, outFile: path.join(cfg.out, `viewer-${name}.png`), minShare: MIN_SHARE[name], log });
    });
  }

  // g. the viewer's relief: colours from the data's own heights, exaggeration, globe position, sea level
  const getJson = async (url) => {
    const r = await fetchWithTimeout(url);
    if (r.status !== 200) throw new CheckFailure(`GET ${url} -> ${r.status}: ${truncate(await r.text(), 300)}`);
    return r.json();
  };
  await checks.run(`g. viewer relief ${RELIEF.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[RELIEF.name], `the bake of ${RELIEF.name} failed`);
    needs(browser, `no browser: ${browserError}`);
    const geo = GEO.find((g) => g.name === RELIEF.name);
    let raster, lonLatOf, geoid;
    try {
      raster = readGeoTiff(path.join(cfg.data, geo.file));
      lonLatOf = toLonLat(raster.epsg);
      geoid = geo.egm96 ? egm96() : null;
    } catch (err) {
      throw new CheckFailure(err.message);
    }
    if (`EPSG:${raster.epsg}` !== RELIEF.globe.crs) throw new CheckFailure(`${geo.file} says EPSG:${raster.epsg}, this check expects ${RELIEF.globe.crs}`);
    // colours are judged against the GeoTIFF's own heights; positions are the ellipsoidal ones
    const place = (col, row) => {
      const s = placeSample(raster, lonLatOf, geoid, col, row);
      return { h: s.value, ecef: s.ecef };
    };
    const summary = await getJson(`${base}/tilesets/${RELIEF.name}`);
    return reliefCheck({ browser, base, name: RELIEF.name, raster, place, summary, expectedGlobe: RELIEF.globe, exaggeration: RELIEF.exaggeration, outDir: cfg.out, log });
  });
  await checks.run(`g. viewer sea level ${SEA.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[SEA.name], `the bake of ${SEA.name} failed`);
    needs(browser, `no browser: ${browserError}`);
    const png = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
    // fuji has no georeference: sample (col, row) lies at (col·cell, row·cell), as in the placement check
    const root = await getJson(`${base}/tilesets/${SEA.name}/3dtiles/tileset.json`);
    let lf;
    try {
      lf = localFrame(root);
    } catch (err) {
      throw new CheckFailure(`${SEA.name}: ${err.message}`);
    }
    const T = root.root?.transform;
    if (!Array.isArray(T) || T.length !== 16) throw new CheckFailure(`${SEA.name}: a tileset in a local frame has no root transform`);
    // a local frame: the root transform is its placement on the globe (checked for fuji above)
    const place = (col, row) => {
      const h = png.at(col, row) + SEA.zOffset;
      return { h, ecef: multiplyPoint(T, toLocal(lf, col * FUJI.cellSize, row * FUJI.cellSize, h)) };
    };
    return seaLevelCheck({ browser, base, name: SEA.name, raster: png, place, outDir: cfg.out, log });
  });
  await checks.run(`g. viewer sea level ${GLOBE_SEA}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[GLOBE_SEA], `the bake of ${GLOBE_SEA} failed`);
    needs(browser, `no browser: ${browserError}`);
    const geo = GEO.find((g) => g.name === GLOBE_SEA);
    let raster, lonLatOf, geoid;
    try {
      raster = readGeoTiff(path.join(cfg.data, geo.file));
      lonLatOf = toLonLat(raster.epsg);
      geoid = geo.egm96 ? egm96() : null;
    } catch (err) {
      throw new CheckFailure(err.message);
    }
    // sea level is the geoid: judged by the raster's own (EGM96) heights, placed where they are
    const place = (col, row) => {
      const s = placeSample(raster, lonLatOf, geoid, col, row);
      return { h: s.value, ecef: s.ecef };
    };
    // finer than the default view's tiles (kilometres of error at the root), so the coasts are
    // drawn where they are
    return seaLevelCheck({ browser, base, name: GLOBE_SEA, raster, place, maxSse: GLOBE_SEA_SSE, outDir: cfg.out, log });
  });

  // i. CesiumJS on the globe terrain: the docs example page, a flight, heights
  for (const { name, imagery } of TERRAIN_CESIUM) {
    const geo = GEO.find((g) => g.name === name);
    const session = {};
    let expected = null;
    let stats = null;
    try {
      const raster = readGeoTiff(path.join(cfg.data, geo.file));
      stats = JSON.parse(fs.readFileSync(path.join(store, name, 'terrain', 'stats.json'), 'utf8'));
      expected = terrainSamples({ raster, geoid: geo.egm96 ? egm96() : null, maxZoom: stats.max_zoom, k: TERRAIN_GRID });
    } catch (err) {
      expected = { error: err.message };
    }
    await checks.run(`i. cesium terrain ${name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      needs(!exampleError, `no example page: ${exampleError}`);
      needs(!expected.error, expected.error);
      needs(expected.length > 0, `no sample point of ${geo.file} has data around it`);
      const lon = expected.reduce((a, s) => a + s.lon, 0) / expected.length;
      const lat = expected.reduce((a, s) => a + s.lat, 0) / expected.length;
      const h = [...expected].sort((a, b) => a.h - b.h)[expected.length >> 1].h;
      const stops = name === 'etopo' ? GLOBE_STOPS : REGIONAL_STOPS.map((s) => ({ lon, lat, h, ...s }));
      const exampleUrl = `${pageBase}/example/${path.basename(EXAMPLE.file)}?server=${encodeURIComponent(base)}&tileset=${encodeURIComponent(name)}${imagery ? '' : '&imagery=none'}`;
      log(`page: ${exampleUrl}`);
      return cesiumTerrainCheck({
        browser, exampleUrl, flightScriptUrl: `${pageBase}/terrain-flight.js`, name, stops, msPerStop: TERRAIN_MS_PER_STOP, viewport: TERRAIN_VIEWPORT,
        screenshot: path.join(cfg.out, `cesium-terrain-${name}.png`), log, session,
      });
    });
    await checks.run(`i. terrain heights ${name}`, async (log) => {
      needs(!expected.error, expected.error);
      needs(expected.length > 0, `no sample point of ${geo.file} has data around it`);
      const zs = stats.per_zoom?.[stats.max_zoom];
      needs(Number.isFinite(zs?.max_error), `stats.json of ${name} has no max_error for zoom ${stats.max_zoom}`);
      log(`${geo.file}: ${expected.length} points, heights ${geo.egm96 ? `EGM96 (+ undulation from ${EGM96_GTX})` : 'as they are (ellipsoidal)'}; stats.json zoom ${stats.max_zoom}: max_error ${zs.max_error.toFixed(3)} m (bound ${zs.bound.toFixed(3)} m)`);
      return terrainHeightsCheck({ session, samples: expected, errMax: zs.max_error, maxZoom: stats.max_zoom, timeoutMs: 90_000, log });
    });
    if (session.rec) fs.writeFileSync(path.join(cfg.out, `cesium-terrain-${name}-requests.txt`), `${session.rec.requests.join('\n')}\n`);
    if (session.page) await session.page.close().catch(() => {});
  }

  // j. 3DTilesRendererJS with its QuantizedMeshPlugin
  await checks.run(`j. 3d-tiles-renderer terrain ${THREE_TERRAIN.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(browser, `no browser: ${browserError}`);
    const geo = GEO.find((g) => g.name === THREE_TERRAIN.name);
    const raster = readGeoTiff(path.join(cfg.data, geo.file));
    const [x, y] = raster.world(raster.width >> 1, raster.height >> 1);
    const [lon, lat] = toLonLat(raster.epsg)(x, y);
    return threeTerrainCheck({
      browser, pageUrl: `${pageBase}/qm-three.html`, terrainUrl: `${base}/tilesets/${THREE_TERRAIN.name}/terrain/`,
      // (the valley floor is at 500–1500 m: the camera 30 km above about the data's middle)
      view: { lon, lat, h: 1500, range: THREE_TERRAIN.range }, minZoom: THREE_TERRAIN.minZoom, timeoutMs: 90_000,
      screenshot: path.join(cfg.out, `3d-tiles-renderer-terrain-${THREE_TERRAIN.name}.png`), log,
    });
  });
  // l. MapLibre GL JS draws the heightmap tiles (raster-dem terrain + hillshade)
  await checks.run(`l. maplibre heightmap ${MAPLIBRE.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(browser, `no browser: ${browserError}`);
    const geo = GEO.find((g) => g.name === MAPLIBRE.name);
    const raster = readGeoTiff(path.join(cfg.data, geo.file));
    const [x, y] = raster.world(raster.width >> 1, raster.height >> 1);
    const [lon, lat] = toLonLat(raster.epsg)(x, y);
    let lo = Infinity;
    let hi = -Infinity;
    for (let r = 0; r < raster.height; r += 4) {
      for (let c = 0; c < raster.width; c += 4) {
        const v = raster.at(c, r);
        if (Number.isFinite(v)) [lo, hi] = [Math.min(lo, v), Math.max(hi, v)];
      }
    }
    const h = await fetchWithTimeout(`${base}/tilesets/${MAPLIBRE.name}/heights?datum=geoid&points=${lon},${lat}`);
    needs(h.ok, `the heights API answered ${h.status}`);
    const expected = (await h.json()).heights[0].h;
    needs(typeof expected === 'number', `no height at ${lon}, ${lat}`);
    return maplibreCheck({
      browser, pageBase, base, name: MAPLIBRE.name, view: { lon, lat, zoom: MAPLIBRE.zoom, pitch: MAPLIBRE.pitch },
      expected, relief: hi - lo, screenshot: path.join(cfg.out, `maplibre-heightmap-${MAPLIBRE.name}.png`), log,
    });
  });

  // k. the same terrain as 3D Tiles
  for (const t of T3D) {
    await checks.run(`k. 3d tiles terrain ${t.name}`, async (log) => {
      needs(served, 'the server is not running');
      return tiles3dTerrainCheck({ base, name: t.name, live: t.live, log });
    });
    await checks.run(`k. cesium 3d tiles terrain ${t.name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      const geo = GEO.find((g) => g.name === t.name);
      const raster = readGeoTiff(path.join(cfg.data, geo.file));
      const maxZoom = JSON.parse(fs.readFileSync(path.join(store, t.name, 'terrain', 'stats.json'), 'utf8')).max_zoom;
      const grid = terrainSamples({ raster, geoid: null, maxZoom, k: t.grid });
      needs(grid.length > 0, `no sample point of ${geo.file} has data around it`);
      const cell = 180 / 64 / 2 ** maxZoom;
      const points = grid.flatMap((s) => [[s.lon, s.lat], [s.lon + cell / 3, s.lat + cell / 3]]);
      const lon = grid.reduce((a, s) => a + s.lon, 0) / grid.length;
      const lat = grid.reduce((a, s) => a + s.lat, 0) / grid.length;
      const h = [...grid].sort((a, b) => a.h - b.h)[grid.length >> 1].h;
      const tolM = Math.max(0.005, 2 ** -22 * ((Math.PI * 6378137) / 2 ** maxZoom));
      return cesium3dTerrainCheck({
        browser, pageUrl: `${pageBase}/terrain3d.html?server=${encodeURIComponent(base)}&tileset=${t.name}`, flightScriptUrl: `${pageBase}/terrain-flight.js`,
        name: t.name, stops: t.stops.map((s) => ({ lon, lat, h, ...s })), msPerStop: T3D_MS_PER_STOP, viewport: TERRAIN_VIEWPORT, points, tolM, maxDiffShare: T3D_MAX_DIFF_SHARE, poleZoneDeg: t.poleZoneDeg,
        screenshot: path.join(cfg.out, `cesium-3dtiles-terrain-${t.name}.png`), log,
      });
    });
  }
}

let geoidGrid = null;
/** The EGM96 grid, read once. */
function egm96() {
  geoidGrid ??= readGtx(EGM96_GTX);
  return geoidGrid;
}

/**
 * Check e's expected heights on the Earth, from the source raster alone: a HEIGHTS_GRID² grid of
 * samples, each → lon/lat by proj4js with the EPSG definition of the GeoTIFF's own key, height =
 * raster value (+ EGM96 undulation where the heights are EGM96).
 */
function expectedSamples(geo) {
  const file = path.join(cfg.data, geo.file);
  try {
    const raster = readGeoTiff(file);
    if (raster.epsg === null) throw new Error(`${file}: no EPSG code in its GeoKeys`);
    const lonLatOf = toLonLat(raster.epsg);
    const geoid = geo.egm96 ? egm96() : null;
    const grid = interiorGrid(raster, HEIGHTS_GRID, { cols: geo.cols, rows: geo.rows });
    const samples = grid.map(({ col, row }) => placeSample(raster, lonLatOf, geoid, col, row));
    const moved = grid.filter((g) => g.moved > 0).length;
    const lines = [`${geo.file}: EPSG:${raster.epsg}, ${raster.width}×${raster.height}, ${raster.pixelIsPoint ? 'PixelIsPoint' : 'PixelIsArea'}; heights ${geo.egm96 ? `EGM96 (+ undulation from ${EGM96_GTX})` : 'as they are (ellipsoidal)'}; ${samples.length} samples${moved ? `, ${moved} moved off no-data` : ''}`];
    return { samples, lines };
  } catch (err) {
    throw new CheckFailure(err.message);
  }
}

try {
  await main();
} catch (err) {
  checks.fail('run', `unexpected error: ${err?.stack ?? err}`);
}
await cleanup();
finish();
clearTimeout(hardTimer);
