// MapLibre GL JS (raster-dem terrain + hillshade) on terrastream's heightmap tiles, in headless
// chromium: no map errors, every heightmap request answered 200, the terrain elevation MapLibre
// reads at the centre within a stated margin of the heights API's answer there, and a picture
// whose hillshade shows relief (compared with the same view without the DEM's hillshade).
import fs from 'node:fs';
import { PNG } from 'pngjs';
import { openRecordedPage } from './browser.mjs';
import { CheckFailure } from './checks.mjs';

/** Standard deviation of the luminance of a PNG screenshot's middle half. */
export function lumaSpread(png) {
  const img = PNG.sync.read(png);
  const [x0, x1, y0, y1] = [img.width >> 2, (3 * img.width) >> 2, img.height >> 2, (3 * img.height) >> 2];
  let n = 0;
  let s = 0;
  let s2 = 0;
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      const k = (y * img.width + x) * 4;
      const l = 0.2126 * img.data[k] + 0.7152 * img.data[k + 1] + 0.0722 * img.data[k + 2];
      n += 1;
      s += l;
      s2 += l * l;
    }
  }
  return Math.sqrt(Math.max(0, s2 / n - (s / n) ** 2));
}

async function render(browser, url, timeoutMs) {
  const { page, rec } = await openRecordedPage(browser);
  try {
    await page.goto(url, { waitUntil: 'load', timeout: timeoutMs });
    await page.waitForFunction(() => window.__result?.idle === true, { timeout: timeoutMs, polling: 250 });
    const result = await page.evaluate(() => window.__result);
    const png = await page.screenshot({ type: 'png' });
    return { result, rec, png };
  } finally {
    await page.close().catch(() => {});
  }
}

/**
 * `expected`: the heights API's answer at (lon, lat) (geoid, the mesh at the finest depth) and
 * `relief`: the data's height range, for the margin.
 */
export async function maplibreCheck({ browser, pageBase, base, name, view, expected, relief, screenshot, log, timeoutMs = 90_000 }) {
  const tiles = `${base}/tilesets/${name}/heightmap/tiles.json`;
  const at = `lon=${view.lon}&lat=${view.lat}&zoom=${view.zoom}&pitch=${view.pitch}`;
  const shaded = await render(browser, `${pageBase}/maplibre.html?tiles=${encodeURIComponent(tiles)}&${at}`, timeoutMs);
  fs.writeFileSync(screenshot, shaded.png);
  const flat = await render(browser, `${pageBase}/maplibre.html?tiles=${encodeURIComponent(tiles)}&${at}&hillshade=0`, timeoutMs);
  const problems = [];
  for (const [what, r] of [['hillshade', shaded], ['no hillshade', flat]]) {
    for (const e of r.result.errors) problems.push(`${what}: map error: ${e}`);
    for (const b of r.rec.badStatus) problems.push(`${what}: ${b}`);
    for (const f of r.rec.failed) problems.push(`${what}: ${f}`);
    for (const e of r.rec.pageErrors) problems.push(`${what}: page error: ${e}`);
  }
  const hmRequests = shaded.rec.requests.filter((u) => u.includes(`/tilesets/${name}/heightmap/`) && u.includes('.png'));
  log(`${hmRequests.length} heightmap tile requests, ${shaded.result.tiles} DEM tiles loaded; elevation at the centre ${shaded.result.elevation} m, heights API ${expected.toFixed(2)} m`);
  if (hmRequests.length === 0) problems.push('MapLibre requested no heightmap tile');
  // MapLibre samples the DEM tile of the zoom it shows (coarser than the data) bilinearly.
  const margin = Math.max(15, 0.05 * relief);
  if (typeof shaded.result.elevation !== 'number' || Math.abs(shaded.result.elevation - expected) > margin) {
    problems.push(`terrain elevation at the centre ${shaded.result.elevation} m, expected ${expected.toFixed(2)} ± ${margin.toFixed(1)} m`);
  }
  const [withShade, without] = [lumaSpread(shaded.png), lumaSpread(flat.png)];
  log(`luminance spread: ${withShade.toFixed(2)} with hillshade, ${without.toFixed(2)} without`);
  if (!(withShade > 4 && withShade > 2 * without)) {
    problems.push(`the hillshade shows no relief: luminance spread ${withShade.toFixed(2)} (without it ${without.toFixed(2)})`);
  }
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
  return `terrain elevation ${shaded.result.elevation.toFixed(1)} m vs ${expected.toFixed(1)} m, ${hmRequests.length} tiles, hillshade spread ${withShade.toFixed(1)} (${without.toFixed(1)} without); ${screenshot}`;
}
