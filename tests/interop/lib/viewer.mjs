// Checks f and g: the server's own /viewer page in headless chromium. f: it loads a tileset and
// draws something. g: on a real DEM it shows relief — colours follow the raster's own heights
// (read here from the source file, not from terrastream), a vertical exaggeration changes the
// picture, the globe position is shown, and sea level is a colour break.
import fs from 'node:fs';
import { createRequire } from 'node:module';
import { CheckFailure } from './checks.mjs';
import { openRecordedPage } from './browser.mjs';
import { truncate } from './walk.mjs';
import { invert, multiplyPoint } from './mat4.mjs';

const require = createRequire(import.meta.url);
const { PNG } = require('pngjs');

const BACKGROUND = [0x1b, 0x1f, 0x24];
const TOLERANCE = 12; // per channel, out of 255

// A pixel's hue is trusted when it is this saturated and this bright (HSV, 0..1): greys and
// near-black pixels have no meaningful hue. Lighting scales a colour's channels together, so it
// changes brightness, not hue: hue is what the height ramp sets.
const MIN_SATURATION = 0.15;
const MIN_VALUE = 0.12;
// g: a colour ramp "with a spread of hues" fills at least HUE_BINS_MIN of twelve 30° hue bins with
// at least HUE_BIN_SHARE of the terrain's pixels each (a ramp stretched over a padded box draws
// one washed-out hue: one bin).
const HUE_BINS_MIN = 3;
const HUE_BIN_SHARE = 0.05;
// g: the lowest and the highest tenth of the raster's samples must be drawn at least this far
// apart in hue (degrees), and hue must follow height: |Spearman ρ| over all samples at least this.
const LOW_HIGH_HUE_MIN = 60;
const MIN_RANK_CORRELATION = 0.7;
const MIN_GROUP_SAMPLES = 25;
// g: the same camera with exaggeration 5 must change at least this share of the terrain's pixels
// by more than PIXEL_DIFF per channel.
const EXAGGERATED_MIN_CHANGE = 0.05;
const PIXEL_DIFF = 24;
// sea level: this share of the samples at least SEA_MARGIN below 0 must be drawn blue (hue
// 180°–260°), and the same share of those at least SEA_MARGIN above 0 must not.
const SEA_SHARE = 0.9;
const SEA_MARGIN = 100;
const BLUE = [180, 260];

/** Share of pixels farther than TOLERANCE (any channel) from the background colour. */
export function nonBackgroundShare(pngBuf) {
  const png = PNG.sync.read(pngBuf);
  const { data, width, height } = png;
  let differ = 0;
  for (let i = 0; i < width * height; i++) if (!isBackground(data, i)) differ++;
  return { share: differ / (width * height), width, height };
}

function isBackground(data, i) {
  return Math.max(
    Math.abs(data[4 * i] - BACKGROUND[0]),
    Math.abs(data[4 * i + 1] - BACKGROUND[1]),
    Math.abs(data[4 * i + 2] - BACKGROUND[2]),
  ) <= TOLERANCE;
}

/** Hue in degrees (NaN for an untrustworthy pixel, see MIN_SATURATION), from 8-bit RGB. */
export function hueOf(r, g, b) {
  const max = Math.max(r, g, b), min = Math.min(r, g, b), d = max - min;
  if (max / 255 < MIN_VALUE || d / max < MIN_SATURATION) return NaN;
  let h;
  if (max === r) h = ((g - b) / d) % 6;
  else if (max === g) h = (b - r) / d + 2;
  else h = (r - g) / d + 4;
  return (h * 60 + 360) % 360;
}

const angleBetween = (a, b) => {
  const d = Math.abs(a - b) % 360;
  return d > 180 ? 360 - d : d;
};
function circularMean(hues) {
  let s = 0, c = 0;
  for (const h of hues) {
    s += Math.sin((h * Math.PI) / 180);
    c += Math.cos((h * Math.PI) / 180);
  }
  return ((Math.atan2(s, c) * 180) / Math.PI + 360) % 360;
}
function ranks(v) {
  const idx = v.map((x, i) => [x, i]).sort((a, b) => a[0] - b[0]);
  const r = new Array(v.length);
  for (let i = 0; i < idx.length;) {
    let j = i;
    while (j + 1 < idx.length && idx[j + 1][0] === idx[i][0]) j++;
    for (let k = i; k <= j; k++) r[idx[k][1]] = (i + j) / 2;
    i = j + 1;
  }
  return r;
}
function spearman(a, b) {
  const ra = ranks(a), rb = ranks(b), n = a.length;
  const ma = ra.reduce((s, x) => s + x, 0) / n, mb = rb.reduce((s, x) => s + x, 0) / n;
  let num = 0, da = 0, db = 0;
  for (let i = 0; i < n; i++) {
    num += (ra[i] - ma) * (rb[i] - mb);
    da += (ra[i] - ma) ** 2;
    db += (rb[i] - mb) ** 2;
  }
  return num / Math.sqrt(da * db);
}
const quantile = (sorted, q) => sorted[Math.min(sorted.length - 1, Math.max(0, Math.round(q * (sorted.length - 1))))];

/**
 * Opens `url` in a recorded page and waits for `window.terrastreamViewer.ready`. Returns
 * `{ page, rec, problems, ready }`; the caller closes the page. `problems` lists what went wrong.
 */
async function openViewer(browser, url, readyTimeoutMs, log) {
  const { page, rec } = await openRecordedPage(browser);
  const problems = [];
  let resp;
  try {
    resp = await page.goto(url, { waitUntil: 'load', timeout: 60_000 });
  } catch (err) {
    await page.close().catch(() => {});
    throw new CheckFailure(`GET ${url} did not load: ${err.message}`);
  }
  if (!resp || resp.status() !== 200) {
    let body = '';
    try {
      body = resp ? await resp.text() : '';
    } catch {
      // ignore
    }
    await page.close().catch(() => {});
    throw new CheckFailure(`GET ${url} -> ${resp ? resp.status() : 'no response'}: the viewer page is missing or broken`, [`body: ${truncate(body, 400)}`]);
  }
  const ready = await waitReady(page, readyTimeoutMs, problems, log);
  return { page, rec, problems, ready };
}

async function waitReady(page, readyTimeoutMs, problems, log) {
  const started = Date.now();
  try {
    await page.waitForFunction(() => window.terrastreamViewer && window.terrastreamViewer.ready === true, { timeout: readyTimeoutMs, polling: 250 });
  } catch {
    let state = 'undefined';
    try {
      state = await page.evaluate(() => {
        try {
          return JSON.stringify(window.terrastreamViewer, (k, v) => (typeof v === 'object' && v && k ? String(v) : v));
        } catch (e) {
          return String(e);
        }
      });
    } catch {
      // ignore
    }
    problems.push(`window.terrastreamViewer.ready did not become true within ${readyTimeoutMs / 1000} s (window.terrastreamViewer = ${truncate(state ?? 'undefined', 300)})`);
    return false;
  }
  log(`ready after ${((Date.now() - started) / 1000).toFixed(1)} s`);
  return true;
}

/** What the recorded page saw go wrong: other hosts, HTTP errors, failed requests, console errors. */
function recordedProblems(rec) {
  const problems = [];
  for (const u of rec.offHost) problems.push(`request to another host (aborted): ${u}`);
  for (const s of rec.badStatus) {
    const hint = s.endsWith('/favicon.ico') ? ' (the page declares no icon, so the browser asks for /favicon.ico: add <link rel="icon" href="data:,"> or serve one)' : '';
    problems.push(`HTTP ${s}${hint}`);
  }
  for (const f of rec.failed) problems.push(`request failed: ${f}`);
  for (const c of rec.consoleErrors) problems.push(`console error: ${truncate(c, 400)}`);
  for (const e of rec.pageErrors) problems.push(`page error: ${truncate(e, 400)}`);
  return problems;
}

export async function viewerCheck({ browser, url, outFile, minShare, readyTimeoutMs = 90_000, log }) {
  const { page, rec, problems, ready } = await openViewer(browser, url, readyTimeoutMs, log);
  try {
    const png = await page.screenshot({ type: 'png' });
    fs.writeFileSync(outFile, png);
    const { share, width, height } = nonBackgroundShare(png);
    log(`screenshot ${outFile} (${width}×${height}): ${(share * 100).toFixed(1)} % of pixels differ from #1b1f24`);
    if (ready && share < minShare) problems.push(`only ${(share * 100).toFixed(1)} % of the pixels differ from the background #1b1f24, need ≥ ${(minShare * 100).toFixed(0)} %`);
    log(`${rec.requests.length} requests`);
    problems.push(...recordedProblems(rec));
    if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
    return `ready, ${(share * 100).toFixed(1)} % non-background pixels (≥ ${(minShare * 100).toFixed(0)} %), ${rec.requests.length} requests, no errors`;
  } finally {
    await page.close().catch(() => {});
  }
}

/**
 * A screenshot with what the analysis needs: the PNG, and the overlay panel's rectangle (its
 * pixels are text, not terrain, and are left out).
 */
async function capture(page, outFile) {
  const buf = await page.screenshot({ type: 'png' });
  fs.writeFileSync(outFile, buf);
  const png = PNG.sync.read(buf);
  const panel = await page.evaluate(() => {
    const r = document.getElementById('panel')?.getBoundingClientRect();
    return r ? [r.left, r.top, r.right, r.bottom] : null;
  });
  const inPanel = (x, y) => panel !== null && x >= panel[0] - 2 && x <= panel[2] + 2 && y >= panel[1] - 2 && y <= panel[3] + 2;
  return { png, inPanel };
}

/** Hue histogram of the terrain's pixels: twelve 30° bins, shares of the terrain pixels. */
function hueBins({ png, inPanel }) {
  const { data, width, height } = png;
  const bins = new Array(12).fill(0);
  let terrain = 0;
  for (let y = 0; y < height; y++) for (let x = 0; x < width; x++) {
    const i = y * width + x;
    if (inPanel(x, y) || isBackground(data, i)) continue;
    terrain++;
    const h = hueOf(data[4 * i], data[4 * i + 1], data[4 * i + 2]);
    if (!Number.isNaN(h)) bins[Math.floor(h / 30) % 12]++;
  }
  return { terrain, shares: bins.map((b) => b / Math.max(terrain, 1)), share: terrain / (width * height) };
}

/** Share of the terrain's pixels (of either image) that differ by more than PIXEL_DIFF. */
function changedShare(a, b) {
  const { data: da, width, height } = a.png, db = b.png.data;
  let terrain = 0, changed = 0;
  for (let y = 0; y < height; y++) for (let x = 0; x < width; x++) {
    const i = y * width + x;
    if (a.inPanel(x, y) || b.inPanel(x, y) || (isBackground(da, i) && isBackground(db, i))) continue;
    terrain++;
    const d = Math.max(Math.abs(da[4 * i] - db[4 * i]), Math.abs(da[4 * i + 1] - db[4 * i + 1]), Math.abs(da[4 * i + 2] - db[4 * i + 2]));
    if (d > PIXEL_DIFF) changed++;
  }
  return changed / Math.max(terrain, 1);
}

/**
 * Raster samples (an n×n grid) with their heights and where they lie on the Earth: `place(col,
 * row)` gives `{ h, ecef }` (the height the colours are judged by, and the Earth-centred
 * position, computed by the caller without the viewer) or null for no-data.
 */
function rasterSamples(raster, n, place) {
  const out = [];
  for (let j = 0; j < n; j++) for (let i = 0; i < n; i++) {
    const col = Math.round((i * (raster.width - 1)) / (n - 1)), row = Math.round((j * (raster.height - 1)) / (n - 1));
    const p = place(col, row);
    if (p && Number.isFinite(p.h) && p.ecef.every(Number.isFinite)) out.push({ col, row, h: p.h, ecef: p.ecef });
  }
  return out;
}

// A sample is judged only when the eye sees it this high above its horizon (sin of the
// elevation): on a globe, the far side projects onto the near side's pixels.
const MIN_ELEVATION = 0.1;
const WGS84_K2 = 1 / (1 - 1 / 298.257223563) ** 2;

/**
 * The hue drawn at each sample (NaN where it is hidden, behind the horizon, off screen, under
 * the panel or grey). Each sample's Earth-centred position goes into the viewer's frame by the
 * inverse of the placement the page reports (`terrastreamViewer.frame.toEcef`), and `project`
 * says which pixel it was drawn at.
 */
async function huesAt(page, shot, samples) {
  const { toEcef, view } = await page.evaluate(() => ({ toEcef: window.terrastreamViewer.frame?.toEcef ?? null, view: window.terrastreamViewer.getView() }));
  if (!Array.isArray(toEcef) || toEcef.length !== 16) throw new CheckFailure(`the viewer reports no frame placement (terrastreamViewer.frame.toEcef is ${JSON.stringify(toEcef)})`);
  const inv = invert(toEcef);
  if (!inv) throw new CheckFailure('the viewer\'s frame placement (terrastreamViewer.frame.toEcef) is singular');
  // the eye, as the viewer's camera puts it (yaw 0: south of the target; pitch: below the horizon)
  const cp = Math.cos(view.pitch);
  const back = [Math.sin(view.yaw) * cp, -Math.cos(view.yaw) * cp, Math.sin(view.pitch)];
  const eye = multiplyPoint(toEcef, view.target.map((t, a) => t + back[a] * view.dist));
  const above = (q) => {
    const n = [q[0], q[1], q[2] * WGS84_K2], d = [eye[0] - q[0], eye[1] - q[1], eye[2] - q[2]];
    return (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / (Math.hypot(...n) * Math.hypot(...d)) >= MIN_ELEVATION;
  };
  const px = await page.evaluate((pts) => pts.map((p) => window.terrastreamViewer.project(p)), samples.map((s) => multiplyPoint(inv, s.ecef)));
  const { data, width, height } = shot.png;
  return samples.map((s, k) => {
    const q = px[k];
    if (!q || !above(s.ecef)) return NaN;
    const x = Math.round(q[0]), y = Math.round(q[1]);
    if (x < 0 || y < 0 || x >= width || y >= height || shot.inPanel(x, y)) return NaN;
    const i = y * width + x;
    if (isBackground(data, i)) return NaN;
    return hueOf(data[4 * i], data[4 * i + 1], data[4 * i + 2]);
  });
}

/**
 * How the drawn hues follow the raster's heights: the circular mean hue of the lowest and the
 * highest tenth of the samples (by the raster's own heights), their difference, and Spearman's
 * ρ between height and hue (hues unwrapped opposite their mean, so a ramp crossing 0° counts).
 */
function hueVersusHeight(samples, hues) {
  const ok = samples.map((s, k) => ({ h: s.h, hue: hues[k] })).filter((x) => !Number.isNaN(x.hue));
  const sorted = samples.map((s) => s.h).sort((a, b) => a - b);
  const p10 = quantile(sorted, 0.1), p90 = quantile(sorted, 0.9);
  const low = ok.filter((x) => x.h <= p10).map((x) => x.hue), high = ok.filter((x) => x.h >= p90).map((x) => x.hue);
  const lowHue = circularMean(low), highHue = circularMean(high);
  const cut = (circularMean(ok.map((x) => x.hue)) + 180) % 360;
  const unwrapped = ok.map((x) => (x.hue - cut + 360) % 360);
  const rho = ok.length > 2 ? spearman(ok.map((x) => x.h), unwrapped) : NaN;
  return { used: ok.length, of: samples.length, p10, p90, low: low.length, high: high.length, lowHue, highHue, apart: angleBetween(lowHue, highHue), rho };
}

function judgeHues(r, what, problems, log) {
  log(`${what}: ${r.used} of ${r.of} raster samples drawn in colour; lowest tenth (≤ ${r.p10.toFixed(0)} m, ${r.low} samples) mean hue ${r.lowHue.toFixed(0)}°, highest tenth (≥ ${r.p90.toFixed(0)} m, ${r.high}) ${r.highHue.toFixed(0)}°: ${r.apart.toFixed(0)}° apart; Spearman ρ(height, hue) ${r.rho.toFixed(3)}`);
  if (r.low < MIN_GROUP_SAMPLES || r.high < MIN_GROUP_SAMPLES) problems.push(`${what}: only ${r.low} low and ${r.high} high raster samples are drawn in colour (need ${MIN_GROUP_SAMPLES} each): the terrain is not where the raster says, or hidden`);
  else if (r.apart < LOW_HIGH_HUE_MIN) problems.push(`${what}: the lowest and highest tenth of the heights are drawn ${r.apart.toFixed(0)}° apart in hue (need ≥ ${LOW_HIGH_HUE_MIN}°): the relief is washed out`);
  if (!(Math.abs(r.rho) >= MIN_RANK_CORRELATION)) problems.push(`${what}: hue follows height with |Spearman ρ| ${Math.abs(r.rho).toFixed(3)} (need ≥ ${MIN_RANK_CORRELATION})`);
}

/**
 * The overlay's globe text, against the server's `globe`. `expected`: null for a tileset without
 * a CRS (the server must give no globe, and the page must say "local frame (no CRS)"), else
 * `{ crs, vertical_datum, lon, lat, tolerance, from }`: the server's globe must exist, name that
 * CRS and datum, and put its centre within `tolerance` degrees of (lon, lat); the page must show
 * that centre.
 */
function judgeGlobe(text, summary, expected, problems, log) {
  log(`globe text: ${JSON.stringify(text)}`);
  const g = summary?.globe;
  if (!expected) {
    if (g !== undefined && g !== null) problems.push(`the tileset has no CRS, but the server gives a globe position: ${truncate(JSON.stringify(g), 300)}`);
    if (!text.includes('local frame (no CRS)')) problems.push(`the tileset has no globe position, and the page does not say "local frame (no CRS)": ${JSON.stringify(text)}`);
    return;
  }
  if (g === undefined || g === null) {
    problems.push(`the source has a CRS (${expected.crs}), but GET /tilesets/{name} gives no "globe" (${JSON.stringify(g)})`);
    return;
  }
  log(`server globe: ${truncate(JSON.stringify(g), 400)}`);
  if (g.crs !== expected.crs) problems.push(`the server's globe.crs is ${JSON.stringify(g.crs)}, the source's CRS is ${expected.crs}`);
  if (g.vertical_datum !== expected.vertical_datum) problems.push(`the server's globe.vertical_datum is ${JSON.stringify(g.vertical_datum)}, the bake asked for ${expected.vertical_datum}`);
  const { lon, lat } = g.centre ?? {};
  if (!Number.isFinite(lon) || !Number.isFinite(lat)) {
    problems.push(`the server's globe.centre is not a longitude and latitude: ${JSON.stringify(g.centre)}`);
    return;
  }
  const fmt = (v, p, n) => `${Math.abs(v).toFixed(4)}°${v < 0 ? n : p}`;
  for (const want of [fmt(lat, 'N', 'S'), fmt(lon, 'E', 'W')]) if (!text.includes(want)) problems.push(`the page's globe text does not show ${want} (the server's globe.centre): ${JSON.stringify(text)}`);
  if (Math.abs(lon - expected.lon) > expected.tolerance || Math.abs(lat - expected.lat) > expected.tolerance) {
    problems.push(`the server's globe.centre ${lat}, ${lon} is not within ${expected.tolerance}° of ${expected.lat}, ${expected.lon} (${expected.from})`);
  }
}

/**
 * Check g on a baked DEM: the default view at 1× and the same camera at `exaggeration`×.
 * `raster`: { width, height } of the source; `place(col, row)`: a sample's height and
 * Earth-centred position (see rasterSamples); `expectedGlobe`: see judgeGlobe.
 */
export async function reliefCheck({ browser, base, name, raster, place, summary, expectedGlobe, exaggeration, outDir, readyTimeoutMs = 90_000, log }) {
  const url = `${base}/viewer?tileset=${encodeURIComponent(name)}`;
  const samples = rasterSamples(raster, 80, place);
  const problems = [];
  let view, range, first;
  {
    const { page, rec, problems: p, ready } = await openViewer(browser, url, readyTimeoutMs, log);
    try {
      problems.push(...p);
      const shot = await capture(page, `${outDir}/viewer-${name}.png`);
      const bins = hueBins(shot);
      const wide = bins.shares.filter((s) => s >= HUE_BIN_SHARE).length;
      log(`screenshot ${outDir}/viewer-${name}.png: terrain ${(bins.share * 100).toFixed(1)} % of the pixels; hue bins (30° each, % of terrain): ${bins.shares.map((s) => (s * 100).toFixed(1)).join(' ')}`);
      if (ready && wide < HUE_BINS_MIN) problems.push(`only ${wide} hue bin(s) of 30° hold ≥ ${HUE_BIN_SHARE * 100} % of the terrain's pixels (need ${HUE_BINS_MIN}): one washed-out colour`);
      const state = await page.evaluate(() => ({
        range: window.terrastreamViewer.heightRange, view: window.terrastreamViewer.getView(), globe: document.getElementById('globe')?.textContent ?? '',
      }));
      ({ view, range } = state);
      log(`colour ramp ${range ? range.map((v) => v.toFixed(1)).join(' … ') : 'none'} m`);
      judgeHues(hueVersusHeight(samples, await huesAt(page, shot, samples)), '1×', problems, log);
      judgeGlobe(state.globe, summary, expectedGlobe, problems, log);
      problems.push(...recordedProblems(rec));
      first = shot;
    } finally {
      await page.close().catch(() => {});
    }
  }
  {
    const { page, rec, problems: p, ready } = await openViewer(browser, `${url}&exaggeration=${exaggeration}`, readyTimeoutMs, log);
    try {
      problems.push(...p);
      const own = `${outDir}/viewer-${name}-x${exaggeration}.png`;
      await capture(page, own);
      log(`screenshot ${own}: the page's own framing at ${exaggeration}×`);
      const state = await page.evaluate(() => ({ e: window.terrastreamViewer.exaggeration, input: document.getElementById('exag')?.value }));
      if (state.e !== exaggeration || Number(state.input) !== exaggeration) problems.push(`exaggeration=${exaggeration} in the URL, but the page has ${state.e} (slider ${state.input})`);
      // The camera of the 1× view: what changes now is the relief alone.
      await page.evaluate((v) => window.terrastreamViewer.setView(v), view);
      if (ready) await waitReady(page, readyTimeoutMs, problems, log);
      const same = await capture(page, `${outDir}/viewer-${name}-x${exaggeration}-same-camera.png`);
      const changed = changedShare(first, same);
      log(`screenshot ${outDir}/viewer-${name}-x${exaggeration}-same-camera.png: ${(changed * 100).toFixed(1)} % of the terrain's pixels differ from 1× by > ${PIXEL_DIFF}/255`);
      if (changed < EXAGGERATED_MIN_CHANGE) problems.push(`exaggeration ${exaggeration}× changes only ${(changed * 100).toFixed(1)} % of the terrain's pixels (need ≥ ${EXAGGERATED_MIN_CHANGE * 100} %)`);
      judgeHues(hueVersusHeight(samples, await huesAt(page, same, samples)), `${exaggeration}×`, problems, log);
      problems.push(...recordedProblems(rec));
    } finally {
      await page.close().catch(() => {});
    }
  }
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
  return `colours follow the raster's heights (low/high tenth apart, hue bins spread), ${exaggeration}× changes the relief, globe position shown`;
}

/**
 * Sea level on a DEM whose heights cross 0 (baked with a negative z offset): samples well below
 * 0 drawn blue, samples well above 0 not. `place` as for reliefCheck, its `h` the height after
 * the offset. `maxSse`: the page's max SSE slider (pixels) for the check, when not its default.
 */
export async function seaLevelCheck({ browser, base, name, raster, place, maxSse, outDir, readyTimeoutMs = 90_000, log }) {
  const url = `${base}/viewer?tileset=${encodeURIComponent(name)}`;
  const samples = rasterSamples(raster, 60, place);
  const { page, rec, problems, ready } = await openViewer(browser, url, readyTimeoutMs, log);
  try {
    if (maxSse !== undefined) {
      await page.evaluate((v) => {
        const el = document.getElementById('sse');
        el.value = String(v);
        el.dispatchEvent(new Event('input'));
      }, maxSse);
      log(`max SSE set to ${maxSse} px`);
      if (ready) await waitReady(page, readyTimeoutMs, problems, log);
    }
    const file = `${outDir}/viewer-${name}.png`;
    const shot = await capture(page, file);
    const hues = await huesAt(page, shot, samples);
    const isBlue = (h) => h >= BLUE[0] && h <= BLUE[1];
    const below = [], above = [];
    samples.forEach((s, k) => {
      if (Number.isNaN(hues[k])) return;
      if (s.h <= -SEA_MARGIN) below.push(hues[k]);
      if (s.h >= SEA_MARGIN) above.push(hues[k]);
    });
    const blueBelow = below.filter(isBlue).length / Math.max(below.length, 1), blueAbove = above.filter(isBlue).length / Math.max(above.length, 1);
    log(`screenshot ${file}: ${below.length} samples ≤ −${SEA_MARGIN} m, ${(blueBelow * 100).toFixed(1)} % drawn blue (hue ${BLUE.join('–')}°); ${above.length} samples ≥ ${SEA_MARGIN} m, ${(blueAbove * 100).toFixed(1)} % drawn blue`);
    if (below.length < MIN_GROUP_SAMPLES || above.length < MIN_GROUP_SAMPLES) problems.push(`too few samples drawn in colour on either side of sea level (${below.length} below, ${above.length} above; need ${MIN_GROUP_SAMPLES})`);
    if (blueBelow < SEA_SHARE) problems.push(`only ${(blueBelow * 100).toFixed(1)} % of the samples below sea level are blue (need ≥ ${SEA_SHARE * 100} %)`);
    if (blueAbove > 1 - SEA_SHARE) problems.push(`${(blueAbove * 100).toFixed(1)} % of the samples above sea level are blue (need ≤ ${((1 - SEA_SHARE) * 100).toFixed(0)} %)`);
    problems.push(...recordedProblems(rec));
    if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
    return `sea level is a colour break: ${(blueBelow * 100).toFixed(0)} % of ${below.length} samples below −${SEA_MARGIN} m blue, ${(blueAbove * 100).toFixed(0)} % of ${above.length} above +${SEA_MARGIN} m`;
  } finally {
    await page.close().catch(() => {});
  }
}
