// Headless Debian chromium through puppeteer-core: launch, and pages that record every request.
import puppeteer from 'puppeteer-core';

export const VIEWPORT = { width: 1024, height: 768 };

export async function launchBrowser(executablePath) {
  return puppeteer.launch({
    executablePath,
    headless: true,
    args: [
      '--no-sandbox',
      '--use-angle=swiftshader',
      '--enable-unsafe-swiftshader',
      '--enable-webgl',
      '--ignore-gpu-blocklist',
      // belt and braces: even a request the interception missed cannot resolve another host
      '--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1',
      '--disable-background-networking',
      '--disable-component-update',
      '--disable-dev-shm-usage',
      '--no-first-run',
      '--no-default-browser-check',
      `--window-size=${VIEWPORT.width},${VIEWPORT.height}`,
    ],
    defaultViewport: VIEWPORT,
    timeout: 60_000,
    protocolTimeout: 240_000,
  });
}

function isLocal(url) {
  let u;
  try {
    u = new URL(url);
  } catch {
    return false;
  }
  // data: and blob: URLs never reach a network; every network scheme must name 127.0.0.1
  if (u.protocol === 'data:' || u.protocol === 'blob:' || u.protocol === 'about:') return true;
  return u.hostname === '127.0.0.1';
}

/**
 * A new 1024×768 page whose requests are all recorded; a request to any host other than
 * 127.0.0.1 is aborted and listed in `rec.offHost`.
 */
export async function openRecordedPage(browser) {
  const page = await browser.newPage();
  await page.setViewport(VIEWPORT);
  const rec = { requests: [], offHost: [], failed: [], cancelled: [], badStatus: [], consoleErrors: [], pageErrors: [], workers: [] };
  await page.setRequestInterception(true);
  page.on('request', (req) => {
    const url = req.url();
    rec.requests.push(url);
    if (!isLocal(url)) {
      rec.offHost.push(url);
      req.abort('blockedbyclient').catch(() => {});
    } else {
      req.continue().catch(() => {});
    }
  });
  page.on('requestfailed', (req) => {
    if (!isLocal(req.url())) return;
    const text = req.failure()?.errorText ?? 'failed';
    // net::ERR_ABORTED on a local request is the client cancelling it (CesiumJS's request
    // scheduler drops tiles it no longer needs when the camera moves on): kept apart, not a
    // server failure. Errors the server causes arrive as other texts or as HTTP statuses.
    if (text === 'net::ERR_ABORTED') rec.cancelled.push(`${req.method()} ${req.url()}`);
    else rec.failed.push(`${req.method()} ${req.url()}: ${text}`);
  });
  page.on('response', (res) => {
    if (res.status() >= 400) rec.badStatus.push(`${res.status()} ${res.request().method()} ${res.url()}`);
  });
  page.on('console', (msg) => {
    if (msg.type() === 'error') {
      const loc = msg.location();
      rec.consoleErrors.push(`${msg.text()}${loc?.url ? ` (${loc.url}:${loc.lineNumber ?? '?'})` : ''}`);
    }
  });
  page.on('pageerror', (err) => rec.pageErrors.push(String(err?.message ?? err)));
  page.on('workercreated', (w) => rec.workers.push(w.url()));
  return { page, rec };
}
