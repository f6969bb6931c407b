// Opens a replay page in Debian's headless Chromium (driven by playwright-core, no bundled browser)
// and checks it as a user would see it: no console or page error, no request but the file itself,
// the summary table, play / pause, the time slider through the frames, a 3D view that is not blank
// and changes between the first and the last frame, the error plot, mouse orbit; then saves a
// screenshot and checks the PNG. Exit code 0 only when every check passes.
//
//   node replay.test.mjs REPLAY.html --screenshot OUT.png [--template host/assets/replay.html]
//
// run.sh builds the demo replay and calls this; see docs/replay.md.

import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { pathToFileURL } from 'node:url';
import { inflateSync } from 'node:zlib';
import { chromium } from 'playwright-core';

const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const ARGS = [
  '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
];
const VIEWPORT = { width: 1280, height: 800 };
const BACKGROUND = [247, 248, 250]; // the 3D view's background, #f7f8fa

function parseArgs(argv) {
  const opts = { replay: null, screenshot: null, template: null };
  for (let i = 0; i < argv.length; i++) {
    if (argv[i] === '--screenshot') opts.screenshot = argv[++i];
    else if (argv[i] === '--template') opts.template = argv[++i];
    else if (!opts.replay) opts.replay = argv[i];
    else throw new Error('unexpected argument ' + argv[i]);
  }
  if (!opts.replay || !opts.screenshot) {
    throw new Error('usage: node replay.test.mjs REPLAY.html --screenshot OUT.png [--template TEMPLATE.html]');
  }
  return opts;
}

let checks = 0;
function ok(what) {
  checks += 1;
  console.log('ok ' + checks + ' - ' + what);
}

// ---------- the data, read by Node itself (to check the page's decoding) ----------
function embeddedDoc(html) {
  const open = '<script id="replay-data" type="application/json">';
  const start = html.indexOf(open);
  assert.ok(start >= 0, 'the page has the data element');
  const end = html.indexOf('</script>', start);
  return JSON.parse(html.slice(start + open.length, end));
}
function f32(b64) {
  const b = Buffer.from(b64, 'base64');
  const out = [];
  for (let i = 0; i + 4 <= b.length; i += 4) out.push(b.readFloatLE(i));
  return out;
}

// ---------- PNG (decoded here, without a library) ----------
const CRC_TABLE = Array.from({ length: 256 }, (_, n) => {
  let c = n;
  for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
  return c >>> 0;
});
function crc32(buf) {
  let c = 0xffffffff;
  for (const byte of buf) c = CRC_TABLE[(c ^ byte) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}
function decodePng(buf) {
  const SIGNATURE = Buffer.from([0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a]);
  assert.ok(buf.subarray(0, 8).equals(SIGNATURE), 'PNG signature');
  let pos = 8, ihdr = null, ended = false;
  const idat = [];
  while (pos < buf.length) {
    const len = buf.readUInt32BE(pos);
    const type = buf.toString('latin1', pos + 4, pos + 8);
    const data = buf.subarray(pos + 8, pos + 8 + len);
    assert.equal(buf.readUInt32BE(pos + 8 + len), crc32(buf.subarray(pos + 4, pos + 8 + len)), 'CRC of chunk ' + type);
    if (type === 'IHDR') {
      ihdr = { width: data.readUInt32BE(0), height: data.readUInt32BE(4), depth: data[8], colour: data[9], interlace: data[12] };
    } else if (type === 'IDAT') idat.push(data);
    else if (type === 'IEND') { ended = true; break; }
    pos += 12 + len;
  }
  assert.ok(ihdr && ended, 'PNG has IHDR and IEND');
  assert.equal(ihdr.depth, 8, 'PNG bit depth');
  assert.equal(ihdr.interlace, 0, 'PNG not interlaced');
  const channels = { 2: 3, 6: 4 }[ihdr.colour];
  assert.ok(channels, 'PNG colour type RGB or RGBA, got ' + ihdr.colour);
  const raw = inflateSync(Buffer.concat(idat));
  const stride = ihdr.width * channels;
  assert.equal(raw.length, ihdr.height * (stride + 1), 'PNG data size');
  const px = Buffer.alloc(ihdr.height * stride);
  for (let y = 0; y < ihdr.height; y++) {
    const filter = raw[y * (stride + 1)];
    for (let x = 0; x < stride; x++) {
      const v = raw[y * (stride + 1) + 1 + x];
      const a = x >= channels ? px[y * stride + x - channels] : 0;
      const b = y > 0 ? px[(y - 1) * stride + x] : 0;
      const c = x >= channels && y > 0 ? px[(y - 1) * stride + x - channels] : 0;
      let pred;
      switch (filter) {
        case 0: pred = 0; break;
        case 1: pred = a; break;
        case 2: pred = b; break;
        case 3: pred = (a + b) >> 1; break;
        case 4: { const p = a + b - c, pa = Math.abs(p - a), pb = Math.abs(p - b), pc = Math.abs(p - c);
          pred = pa <= pb && pa <= pc ? a : pb <= pc ? b : c; break; }
        default: throw new Error('PNG filter ' + filter);
      }
      px[y * stride + x] = (v + pred) & 0xff;
    }
  }
  return { width: ihdr.width, height: ihdr.height, channels, px };
}
// Pixel statistics of an RGB(A) buffer within a rectangle.
function pixelStats(img, rect, background) {
  const colours = new Set();
  let nonBackground = 0, n = 0;
  for (let y = rect.y; y < rect.y + rect.height; y++) {
    for (let x = rect.x; x < rect.x + rect.width; x++) {
      const i = (y * img.width + x) * img.channels;
      const r = img.px[i], g = img.px[i + 1], b = img.px[i + 2];
      n += 1;
      if (Math.abs(r - background[0]) + Math.abs(g - background[1]) + Math.abs(b - background[2]) > 24) nonBackground += 1;
      colours.add((r >> 4) << 8 | (g >> 4) << 4 | (b >> 4));
    }
  }
  return { fraction: nonBackground / n, colours: colours.size };
}

// ---------- in the page ----------
// Statistics of a canvas's pixels, and the fraction of pixels that differ from a snapshot, below
// the top band where the view writes the time and the step (which change with every frame).
function canvasStats([id, background, snapshotName]) {
  const TOP_BAND = 30;
  const canvas = document.getElementById(id);
  const data = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
  const colours = new Set();
  let nonBackground = 0, differ = 0;
  const snap = snapshotName ? window['__snap_' + snapshotName] : null;
  for (let i = 0; i < data.length; i += 4) {
    const r = data[i], g = data[i + 1], b = data[i + 2];
    if (Math.abs(r - background[0]) + Math.abs(g - background[1]) + Math.abs(b - background[2]) > 24) nonBackground += 1;
    colours.add((r >> 4) << 8 | (g >> 4) << 4 | (b >> 4));
    if (snap && i >= 4 * canvas.width * TOP_BAND && (Math.abs(r - snap[i]) + Math.abs(g - snap[i + 1]) + Math.abs(b - snap[i + 2]) > 24)) differ += 1;
  }
  const n = data.length / 4;
  return { width: canvas.width, height: canvas.height, fraction: nonBackground / n, colours: colours.size, differ: snap ? differ / n : null };
}
function canvasSnapshot([id, name]) {
  const canvas = document.getElementById(id);
  window['__snap_' + name] = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data.slice();
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const replayPath = resolve(opts.replay);
  const replayUrl = pathToFileURL(replayPath).href;
  const doc = embeddedDoc(readFileSync(replayPath, 'utf8'));
  const frameCount = doc.frames.length;
  assert.ok(frameCount >= 2, 'the replay has at least two frames');

  const userDataDir = mkdtempSync(join(tmpdir(), 'needle-chromium-'));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM, headless: true, args: ARGS, viewport: VIEWPORT, deviceScaleFactor: 1,
  });
  const requests = [];
  const problems = [];
  context.on('request', (r) => requests.push(r.url()));
  try {
    const page = context.pages()[0] || await context.newPage();
    page.on('console', (m) => { if (m.type() === 'error') problems.push('console error: ' + m.text()); });
    page.on('pageerror', (e) => problems.push('page error: ' + e.message));
    page.on('requestfailed', (r) => problems.push('request failed: ' + r.url()));

    await page.goto(replayUrl, { waitUntil: 'load' });
    await page.waitForFunction(() => window.needleReplay && (window.needleReplay.ready || window.needleReplay.error), null, { timeout: 30000 });
    assert.equal(await page.evaluate(() => window.needleReplay.error), null, 'the page reads its data');
    assert.equal(await page.evaluate(() => window.needleReplay.frames), frameCount);
    ok('the page loads and reads its ' + frameCount + ' frames');

    // The browser decodes the same floats as Node does from the file.
    const decoded = await page.evaluate((n) => {
      const d = window.needleReplay.data;
      return { surface: Array.from(d.frames[0].surface.slice(0, 30)), needle: Array.from(d.frames[n - 1].needle), target: Array.from(d.frames[n - 1].target) };
    }, frameCount);
    assert.deepEqual(decoded.surface, f32(doc.frames[0].surface).slice(0, 30));
    assert.deepEqual(decoded.needle, f32(doc.frames[frameCount - 1].needle));
    assert.deepEqual(decoded.target, f32(doc.frames[frameCount - 1].target));
    ok('the page decodes the same Float32 values as Node (first surface nodes, last needle and target)');

    // The summary table shows the summary's rows.
    const rows = await page.locator('#summary tr').evaluateAll((trs) => trs.map((tr) => [tr.cells[0].textContent, tr.cells[1].textContent]));
    assert.ok(doc.summary.length > 0, 'the replay has a summary');
    assert.deepEqual(rows, doc.summary);
    assert.ok(await page.locator('#summary').isVisible(), 'the summary table is visible');
    ok('the summary table shows ' + rows.length + ' rows');

    // Frame 0: the 3D view is not blank.
    const first = await page.evaluate(canvasStats, ['view', BACKGROUND, null]);
    assert.ok(first.width >= 300 && first.height >= 300, '3D canvas size ' + first.width + 'x' + first.height);
    assert.ok(first.fraction > 0.05, 'first frame: ' + (100 * first.fraction).toFixed(1) + ' % of the pixels are not background');
    assert.ok(first.colours >= 12, 'first frame: ' + first.colours + ' colours');
    await page.evaluate(canvasSnapshot, ['view', 'first']);
    ok('first frame rendered: ' + (100 * first.fraction).toFixed(1) + ' % drawn, ' + first.colours + ' colours');

    const plot = await page.evaluate(canvasStats, ['plot', [255, 255, 255], null]);
    assert.ok(plot.fraction > 0.01 && plot.colours >= 4, 'error plot drawn: ' + JSON.stringify(plot));
    ok('error plot drawn: ' + (100 * plot.fraction).toFixed(1) + ' % drawn, ' + plot.colours + ' colours');

    // Play, then pause.
    await page.click('#play');
    assert.equal(await page.textContent('#play'), 'Pause');
    await page.waitForFunction(() => window.needleReplay.frame() >= 2, null, { timeout: 15000 });
    await page.click('#play');
    assert.equal(await page.textContent('#play'), 'Play');
    assert.equal(await page.evaluate(() => window.needleReplay.playing()), false);
    const paused = await page.evaluate(() => window.needleReplay.frame());
    await page.waitForTimeout(400);
    assert.equal(await page.evaluate(() => window.needleReplay.frame()), paused, 'paused stays on its frame');
    ok('play advances (paused at frame ' + paused + '), pause holds');

    // The slider through the frames, the label and the render following it.
    const targets = [...new Set(Array.from({ length: 9 }, (_, k) => Math.round(k * (frameCount - 1) / 8)))];
    for (const i of targets) {
      await page.locator('#slider').fill(String(i));
      await page.waitForFunction((j) => window.needleReplay.rendered === j, i, { timeout: 10000 });
      const label = await page.textContent('#frame-label');
      assert.ok(label.startsWith('frame ' + (i + 1) + ' / ' + frameCount + ' · step ' + doc.frames[i].step + ' '), label);
      const s = await page.evaluate(canvasStats, ['view', BACKGROUND, null]);
      assert.ok(s.fraction > 0.05 && s.colours >= 12, 'frame ' + i + ': ' + JSON.stringify(s));
    }
    ok('slider to frames ' + targets.join(', ') + ': label and render follow');
    // The keyboard steps one frame back.
    await page.evaluate(() => document.activeElement && document.activeElement.blur());
    await page.keyboard.press('ArrowLeft');
    await page.waitForFunction((j) => window.needleReplay.rendered === j, frameCount - 2, { timeout: 10000 });
    await page.keyboard.press('ArrowRight');
    await page.waitForFunction((j) => window.needleReplay.rendered === j, frameCount - 1, { timeout: 10000 });
    ok('arrow keys step one frame');

    const last = await page.evaluate(canvasStats, ['view', BACKGROUND, 'first']);
    assert.ok(last.differ > 0.002, 'first and last frames differ on ' + (100 * last.differ).toFixed(2) + ' % of the pixels');
    ok('first and last frames render differently (' + (100 * last.differ).toFixed(2) + ' % of the pixels)');

    // Mouse orbit and zoom change the view; a double-click brings the default view back.
    await page.evaluate(canvasSnapshot, ['view', 'before_orbit']);
    const box = await page.locator('#view').boundingBox();
    await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
    await page.mouse.down();
    await page.mouse.move(box.x + box.width / 2 + 120, box.y + box.height / 2 + 40, { steps: 6 });
    await page.mouse.up();
    await page.mouse.wheel(0, -300);
    await page.waitForTimeout(100);
    const orbit = await page.evaluate(canvasStats, ['view', BACKGROUND, 'before_orbit']);
    assert.ok(orbit.differ > 0.01 && orbit.fraction > 0.05, 'orbit and zoom change the view: ' + JSON.stringify(orbit));
    await page.mouse.dblclick(box.x + box.width / 2, box.y + box.height / 2);
    await page.waitForTimeout(100);
    const reset = await page.evaluate(canvasStats, ['view', BACKGROUND, 'before_orbit']);
    assert.ok(reset.differ < 0.001, 'double-click restores the default view: ' + JSON.stringify(reset));
    ok('mouse orbit and zoom change the view (' + (100 * orbit.differ).toFixed(1) + ' % of the pixels), double-click restores it');

    // The plot against depth, then the screenshot at 70 % of the insertion.
    await page.selectOption('#plot-x', 'depth');
    const shotFrame = Math.round(0.7 * (frameCount - 1));
    await page.locator('#slider').fill(String(shotFrame));
    await page.waitForFunction((j) => window.needleReplay.rendered === j, shotFrame, { timeout: 10000 });
    await page.waitForTimeout(100);
    const plotDepth = await page.evaluate(canvasStats, ['plot', [255, 255, 255], null]);
    assert.ok(plotDepth.fraction > 0.01, 'error plot against depth drawn');
    ok('error plot against depth drawn');

    await page.evaluate(() => document.activeElement && document.activeElement.blur());
    const png = await page.screenshot({ fullPage: true });
    writeFileSync(opts.screenshot, png);
    const img = decodePng(png);
    assert.equal(img.width, VIEWPORT.width, 'screenshot width');
    assert.ok(img.height >= VIEWPORT.height, 'screenshot height ' + img.height);
    const whole = pixelStats(img, { x: 0, y: 0, width: img.width, height: img.height }, [255, 255, 255]);
    assert.ok(whole.colours >= 64, 'screenshot has ' + whole.colours + ' colours');
    const viewBox = await page.locator('#view').boundingBox();
    const inView = pixelStats(img, {
      x: Math.ceil(viewBox.x) + 2, y: Math.ceil(viewBox.y) + 2,
      width: Math.floor(viewBox.width) - 4, height: Math.floor(viewBox.height) - 4,
    }, BACKGROUND);
    assert.ok(inView.fraction > 0.05 && inView.colours >= 12, '3D view in the screenshot: ' + JSON.stringify(inView));
    ok('screenshot ' + opts.screenshot + ': ' + img.width + 'x' + img.height + ', ' + whole.colours + ' colours, 3D view '
      + (100 * inView.fraction).toFixed(1) + ' % drawn');

    // The template alone says it has no data, without an error.
    if (opts.template) {
      const empty = await context.newPage();
      empty.on('console', (m) => { if (m.type() === 'error') problems.push('template: console error: ' + m.text()); });
      empty.on('pageerror', (e) => problems.push('template: page error: ' + e.message));
      await empty.goto(pathToFileURL(resolve(opts.template)).href, { waitUntil: 'load' });
      await empty.waitForFunction(() => window.needleReplay && window.needleReplay.ready, null, { timeout: 10000 });
      assert.equal(await empty.evaluate(() => window.needleReplay.empty), true);
      assert.match(await empty.textContent('#status'), /no data embedded/);
      await empty.close();
      ok('the template without data says so');
    }

    assert.deepEqual(problems, [], 'no console error, page error or failed request');
    ok('no console error, page error or failed request');
    const allowed = new Set([replayUrl, opts.template ? pathToFileURL(resolve(opts.template)).href : replayUrl]);
    const foreign = requests.filter((u) => !allowed.has(u));
    assert.deepEqual(foreign, [], 'no request other than the file itself');
    assert.ok(requests.includes(replayUrl), 'the file itself was requested');
    ok('requests: only the file itself (' + requests.length + ' in all)');
  } finally {
    await context.close();
    rmSync(userDataDir, { recursive: true, force: true });
  }
  console.log('all ' + checks + ' checks passed');
}

main().catch((e) => {
  console.error('FAILED: ' + (e && e.stack ? e.stack : e));
  process.exit(1);
});
