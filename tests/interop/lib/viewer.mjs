// Check f: the server's own /viewer page in headless chromium.
import fs from 'node:fs';
import { createRequire } from 'node:module';
import { CheckFailure } from './checks.mjs';
import { openRecordedPage } from './browser.mjs';
import { truncate } from './walk.mjs';

const require = createRequire(import.meta.url);
const { PNG } = require('pngjs');

const BACKGROUND = [0x1b, 0x1f, 0x24];
const TOLERANCE = 12; // per channel, out of 255

/** Share of pixels farther than TOLERANCE (any channel) from the background colour. */
export function nonBackgroundShare(pngBuf) {
  const png = PNG.sync.read(pngBuf);
  const { data, width, height } = png;
  let differ = 0;
  for (let i = 0; i < width * height; i++) {
    const d = Math.max(
      Math.abs(data[4 * i] - BACKGROUND[0]),
      Math.abs(data[4 * i + 1] - BACKGROUND[1]),
      Math.abs(data[4 * i + 2] - BACKGROUND[2]),
    );
    if (d > TOLERANCE) differ++;
  }
  return { share: differ / (width * height), width, height };
}

export async function viewerCheck({ browser, url, outFile, minShare, readyTimeoutMs = 90_000, log }) {
  const { page, rec } = await openRecordedPage(browser);
  const problems = [];
  try {
    let resp;
    try {
      resp = await page.goto(url, { waitUntil: 'load', timeout: 60_000 });
    } catch (err) {
      throw new CheckFailure(`GET ${url} did not load: ${err.message}`);
    }
    if (!resp) throw new CheckFailure(`GET ${url}: no response`);
    if (resp.status() !== 200) {
      let body = '';
      try {
        body = await resp.text();
      } catch {
        // ignore
      }
      throw new CheckFailure(`GET ${url} -> ${resp.status()}: the viewer page is missing or broken`, [`body: ${truncate(body, 400)}`]);
    }
    const started = Date.now();
    let ready = true;
    try {
      await page.waitForFunction(() => window.terrastreamViewer && window.terrastreamViewer.ready === true, { timeout: readyTimeoutMs, polling: 250 });
    } catch {
      ready = false;
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
    }
    if (ready) log(`ready after ${((Date.now() - started) / 1000).toFixed(1)} s`);
    const png = await page.screenshot({ type: 'png' });
    fs.writeFileSync(outFile, png);
    const { share, width, height } = nonBackgroundShare(png);
    log(`screenshot ${outFile} (${width}×${height}): ${(share * 100).toFixed(1)} % of pixels differ from #1b1f24`);
    if (ready && share < minShare) problems.push(`only ${(share * 100).toFixed(1)} % of the pixels differ from the background #1b1f24, need ≥ ${(minShare * 100).toFixed(0)} %`);
    log(`${rec.requests.length} requests`);
    for (const u of rec.offHost) problems.push(`request to another host (aborted): ${u}`);
    for (const s of rec.badStatus) {
      const hint = s.endsWith('/favicon.ico') ? ' (the page declares no icon, so the browser asks for /favicon.ico: add <link rel="icon" href="data:,"> or serve one)' : '';
      problems.push(`HTTP ${s}${hint}`);
    }
    for (const f of rec.failed) problems.push(`request failed: ${f}`);
    for (const c of rec.consoleErrors) problems.push(`console error: ${truncate(c, 400)}`);
    for (const e of rec.pageErrors) problems.push(`page error: ${truncate(e, 400)}`);
    if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
    return `ready, ${(share * 100).toFixed(1)} % non-background pixels (≥ ${(minShare * 100).toFixed(0)} %), ${rec.requests.length} requests, no errors`;
  } finally {
    await page.close().catch(() => {});
  }
}
