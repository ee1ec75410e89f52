#!/usr/bin/env node
// Opens a `gardefou report` HTML file in headless Chromium and prints ONE JSON
// object describing what the browser saw: render time, console errors, uncaught
// exceptions, attempted network requests, how much of the screenshot is drawn,
// and the parts / timeline bands / explanations / pictures found in the DOM.
//
//   node tests/browser/check-report.mjs REPORT.html SCREENSHOT.png
//
// Exit 0 whenever the JSON could be produced (the caller judges it); non-zero
// with a one-line message on stderr when the browser could not be used at all.
// Uses the system Chromium (/usr/bin/chromium, else `chromium` on PATH, or
// $CHROMIUM_PATH) through playwright-core, which never downloads a browser.

import fs from 'node:fs';
import path from 'node:path';
import { pathToFileURL } from 'node:url';
import { chromium } from 'playwright-core';

const RENDER_TIMEOUT_MS = 30_000;
const VIEWPORT = { width: 1400, height: 1000 };
// The report must be self-contained: only these schemes may be requested.
const LOCAL_SCHEMES = ['file:', 'data:', 'about:', 'blob:'];

function fail(message) {
  process.stderr.write(`check-report: ${String(message).split('\n')[0]}\n`);
  process.exit(2);
}

function chromiumPath() {
  if (process.env.CHROMIUM_PATH) return process.env.CHROMIUM_PATH;
  if (fs.existsSync('/usr/bin/chromium')) return '/usr/bin/chromium';
  for (const dir of (process.env.PATH || '').split(path.delimiter)) {
    for (const name of ['chromium', 'chromium-browser']) {
      const p = path.join(dir, name);
      if (dir && fs.existsSync(p)) return p;
    }
  }
  return '/usr/bin/chromium';
}

const isLocal = (url) => LOCAL_SCHEMES.some((s) => url.startsWith(s));

async function main() {
  const [reportArg, shotArg] = process.argv.slice(2);
  if (!reportArg || !shotArg) fail('usage: check-report.mjs REPORT.html SCREENSHOT.png');
  const report = path.resolve(reportArg);
  const shot = path.resolve(shotArg);
  if (!fs.existsSync(report)) fail(`no such report: ${report}`);

  let browser;
  try {
    browser = await chromium.launch({
      executablePath: chromiumPath(),
      timeout: 60_000,
      // The background-networking flags keep Chromium itself from reaching out
      // (updates, sync, field trials): the machine may have no network at all.
      args: [
        '--headless',
        '--no-sandbox',
        '--disable-gpu',
        '--disable-quic',
        '--no-first-run',
        '--disable-background-networking',
        '--disable-component-update',
        '--disable-sync',
      ],
    });
  } catch (e) {
    fail(`could not launch Chromium (${chromiumPath()}): ${e.message}`);
  }

  try {
    const out = await inspect(browser, report, shot);
    process.stdout.write(JSON.stringify(out) + '\n');
  } finally {
    await browser.close().catch(() => {});
  }
}

async function inspect(browser, report, shot) {
  const context = await browser.newContext({ viewport: VIEWPORT, deviceScaleFactor: 1 });
  const page = await context.newPage();
  page.setDefaultTimeout(120_000);

  const consoleErrors = [];
  const consoleWarnings = [];
  const pageErrors = [];
  const network = [];
  const noteNetwork = (url) => {
    if (!isLocal(url) && !network.includes(url)) network.push(url);
  };

  page.on('console', (msg) => {
    const loc = msg.location();
    const where = loc && loc.url ? ` (${path.basename(loc.url)}:${loc.lineNumber})` : '';
    if (msg.type() === 'error') consoleErrors.push(msg.text() + where);
    else if (msg.type() === 'warning') consoleWarnings.push(msg.text() + where);
  });
  page.on('pageerror', (err) => pageErrors.push(String(err && err.message ? err.message : err)));
  // Blocked, and recorded: anything leaving the machine is a defect of the report.
  await page.route('**/*', (route) => {
    const url = route.request().url();
    if (isLocal(url)) return route.continue();
    noteNetwork(url);
    return route.abort('blockedbyclient');
  });
  page.on('request', (req) => noteNetwork(req.url()));
  page.on('websocket', (ws) => noteNetwork(ws.url()));

  const t0 = performance.now();
  let renderError = null;
  let renderedMs = null;
  let loadMs = null;
  try {
    await page.goto(pathToFileURL(report).href, { waitUntil: 'load', timeout: RENDER_TIMEOUT_MS });
    await page.waitForFunction(
      () => {
        const d = document.documentElement.dataset;
        return d.rendered !== undefined || d.renderError !== undefined;
      },
      null,
      { timeout: RENDER_TIMEOUT_MS, polling: 20 },
    );
    loadMs = Math.round(performance.now() - t0);
    // A moment for errors thrown just after the first draw to surface.
    await page.waitForTimeout(250);
    const state = await page.evaluate(() => ({
      rendered: document.documentElement.dataset.rendered ?? null,
      error: document.documentElement.dataset.renderError ?? null,
    }));
    renderError = state.error;
    if (state.rendered !== null && state.rendered !== '') {
      const n = Number(state.rendered);
      renderedMs = Number.isFinite(n) ? n : null;
    }
  } catch (e) {
    renderError = `not rendered within ${RENDER_TIMEOUT_MS} ms: ${String(e.message).split('\n')[0]}`;
  }

  const dom = await page.evaluate(() => {
    const num = (v) => (v !== undefined && v !== null && v !== '' && !Number.isNaN(Number(v)) ? Number(v) : v ?? null);
    const parts = [...document.querySelectorAll('table.summary tr[data-part]')].map((tr) => ({
      log: num(tr.dataset.log),
      part: tr.dataset.part,
      labels: (tr.querySelector('td.labels')?.textContent ?? '').trim(),
    }));
    const timelines = [...document.querySelectorAll('svg.timeline')].map((svg) => ({
      log: num(svg.dataset.log),
      part: svg.dataset.part ?? null,
      bands: [...svg.querySelectorAll('g.band[data-signal]')].map((g) => g.dataset.signal),
      // Shapes drawn per band besides its label: an empty band draws none.
      shapes: Object.fromEntries(
        [...svg.querySelectorAll('g.band[data-signal]')].map((g) => [
          g.dataset.signal,
          g.querySelectorAll('rect, path').length,
        ]),
      ),
    }));
    // The page background as RGB, whatever CSS colour syntax the stylesheet uses:
    // let a canvas resolve it. Transparent body → the root's → white.
    const rgb = (css) => {
      const c = document.createElement('canvas').getContext('2d');
      c.fillStyle = '#000';
      c.fillStyle = css;
      c.fillRect(0, 0, 1, 1);
      const [r, g, b, a] = c.getImageData(0, 0, 1, 1).data;
      return a === 0 ? null : [r, g, b];
    };
    const background =
      (document.body && rgb(getComputedStyle(document.body).backgroundColor)) ||
      rgb(getComputedStyle(document.documentElement).backgroundColor) || [255, 255, 255];
    return {
      parts,
      timelines,
      explanations: document.querySelectorAll('article.explanation').length,
      pictures: document.querySelectorAll('figure.model-picture svg').length,
      background,
    };
  });

  await page.screenshot({ path: shot, fullPage: true, timeout: 120_000 });
  const screenshot = await measureScreenshot(context, shot, dom.background);

  // The turntable's timeline alone, against its own card: a page of empty cards
  // would pass the whole-page measure, not this one.
  let turntableTimeline = null;
  const svg = page.locator('svg.timeline[data-part="turntable"]').first();
  if ((await svg.count()) > 0) {
    const cardBackground = await svg.evaluate((el) => {
      const c = document.createElement('canvas').getContext('2d');
      let node = el;
      while (node && node instanceof Element) {
        const bg = getComputedStyle(node).backgroundColor;
        c.clearRect(0, 0, 1, 1);
        c.fillStyle = '#000';
        c.fillStyle = bg;
        c.fillRect(0, 0, 1, 1);
        const [r, g, b, a] = c.getImageData(0, 0, 1, 1).data;
        if (a > 0 && bg !== 'rgba(0, 0, 0, 0)') return [r, g, b];
        node = node.parentElement;
      }
      return [255, 255, 255];
    });
    const elementShot = shot.replace(/\.png$/, '') + '-turntable.png';
    await svg.screenshot({ path: elementShot, timeout: 60_000 });
    turntableTimeline = await measureScreenshot(context, elementShot, cardBackground);
  }

  return {
    rendered_ms: renderedMs,
    render_error: renderError,
    load_ms: loadMs,
    console_errors: consoleErrors,
    console_warnings: consoleWarnings,
    page_errors: pageErrors,
    network,
    screenshot,
    turntable_timeline: turntableTimeline,
    parts: dom.parts,
    timelines: dom.timelines,
    explanations: dom.explanations,
    pictures: dom.pictures,
  };
}

// Decodes the PNG in the browser itself (a fresh page, the image as a data URL,
// drawn into a canvas), so no native image library is needed. Counts the pixels
// that differ from the page background and the distinct colours.
async function measureScreenshot(context, shot, background) {
  const png = fs.readFileSync(shot).toString('base64');
  const page = await context.newPage();
  try {
    await page.goto('about:blank');
    return await page.evaluate(
      async ({ png, background }) => {
        const img = new Image();
        img.src = `data:image/png;base64,${png}`;
        await img.decode();
        const width = img.naturalWidth;
        const height = img.naturalHeight;
        const canvas = document.createElement('canvas');
        canvas.width = width;
        canvas.height = height;
        const ctx = canvas.getContext('2d', { willReadFrequently: true });
        ctx.drawImage(img, 0, 0);
        const [br, bg, bb] = background;
        const colours = new Set();
        let differing = 0;
        // Read in strips: a day-long report's full-page screenshot is tall.
        const STRIP = 512;
        for (let y = 0; y < height; y += STRIP) {
          const h = Math.min(STRIP, height - y);
          const d = ctx.getImageData(0, y, width, h).data;
          for (let i = 0; i < d.length; i += 4) {
            const r = d[i];
            const g = d[i + 1];
            const b = d[i + 2];
            // A small tolerance: anti-aliasing of the background itself is not drawing.
            if (Math.abs(r - br) > 8 || Math.abs(g - bg) > 8 || Math.abs(b - bb) > 8) differing++;
            colours.add((r << 16) | (g << 8) | b);
          }
        }
        const total = width * height;
        return {
          width,
          height,
          non_background_fraction: total ? Number((differing / total).toFixed(6)) : 0,
          distinct_colours: colours.size,
          background: `rgb(${br}, ${bg}, ${bb})`,
        };
      },
      { png, background },
    );
  } finally {
    await page.close().catch(() => {});
  }
}

main().catch((e) => fail(e && e.message ? e.message : e));
