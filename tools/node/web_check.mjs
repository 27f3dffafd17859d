// Opens an `s2r export web` folder in headless Chromium (Debian's, driven by
// playwright-core) with software WebGL (SwiftShader), from a static server on
// loopback, at the pose of an s2r.view file; waits for the first frame;
// saves the canvas as PNG; compares it with a reference image (what
// `s2r render --pose` drew) decoded by the browser itself; reports every
// console error and uncaught exception; then (unless --interact 0) opens it
// as a person would and checks that orbit, pan, zoom and a jump to another
// camera each draw (about 15 s of software rendering). Prints one JSON line; exit 0 when the
// page drew without errors and PSNR >= --min-psnr, 1 otherwise, 2 on a usage
// or start-up problem.
//
// node tools/node/web_check.mjs --dir EXPORT --view VIEW.json --ref REF.png
//      --out SHOT.png [--min-psnr 30] [--interact 1] [--chromium /usr/bin/chromium] [--timeout-ms 120000]
import fs from 'fs';
import http from 'http';
import path from 'path';
import { chromium } from 'playwright-core';

const args = {};
for (let i = 2; i < process.argv.length; i += 2) args[process.argv[i].replace(/^--/, '')] = process.argv[i + 1];
for (const k of ['dir', 'view', 'ref', 'out'])
  if (!args[k]) { console.error(`web_check: --${k} is required`); process.exit(2); }
const minPsnr = Number(args['min-psnr'] ?? 30);
const timeout = Number(args['timeout-ms'] ?? 120000);
const interact = (args.interact ?? '1') !== '0';

const files = { '/view.json': path.resolve(args.view), '/reference.png': path.resolve(args.ref) };
const types = { '.html': 'text/html', '.js': 'text/javascript', '.json': 'application/json', '.png': 'image/png' };
const server = http.createServer((req, res) => {
  const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  const file = files[url] ?? path.join(path.resolve(args.dir), path.normalize(url).replace(/^(\.\.[/\\])+/, ''));
  fs.readFile(file, (err, data) => {
    if (err) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'Content-Type': types[path.extname(file)] ?? 'application/octet-stream' });
    res.end(data);
  });
});
await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
const port = server.address().port;

let browser;
try {
  browser = await chromium.launch({
    executablePath: args.chromium ?? '/usr/bin/chromium',
    args: ['--headless=new', '--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--disable-background-networking', '--disable-component-update', '--disable-sync', '--no-first-run',
      '--disable-quic'],
  });
} catch (e) {
  console.error(`web_check: Chromium did not start: ${e.message}`);
  server.close();
  process.exit(2);
}
const errors = [];
const page = await browser.newPage({ viewport: { width: 1400, height: 1000 }, deviceScaleFactor: 1 });
page.on('console', (m) => { if (m.type() === 'error') errors.push(`console: ${m.text()}`); });
page.on('pageerror', (e) => errors.push(`exception: ${e.message}`));
page.on('requestfailed', (r) => errors.push(`request failed: ${r.url()}`));
const started = Date.now();
await page.goto(`http://127.0.0.1:${port}/index.html?view=view.json`);
try {
  await page.waitForFunction(() => window.s2r && (window.s2r.ready || window.s2r.error), null, { timeout, polling: 200 });
} catch (e) {
  errors.push(`no first frame within ${timeout} ms`);
}
const loadMs = Date.now() - started;
const state = await page.evaluate(() => window.s2r ? { ready: window.s2r.ready, error: window.s2r.error ?? null,
  drawn: window.s2r.drawn ?? 0, frameMs: window.s2r.lastFrameMs ?? 0 } : null);
const result = await page.evaluate(async () => {
  const gl = document.getElementById('view');
  const w = gl.width, h = gl.height;
  const c1 = new OffscreenCanvas(w, h).getContext('2d');
  c1.drawImage(gl, 0, 0);
  const a = c1.getImageData(0, 0, w, h).data;
  const img = new Image();
  img.src = 'reference.png';
  await img.decode();
  if (img.width !== w || img.height !== h) return { error: `reference is ${img.width}x${img.height}, the page drew ${w}x${h}` };
  const c2 = new OffscreenCanvas(w, h).getContext('2d');
  c2.drawImage(img, 0, 0);
  const b = c2.getImageData(0, 0, w, h).data;
  let se = 0, differing = 0;
  for (let i = 0; i < a.length; i += 4) {
    let px = 0;
    for (let c = 0; c < 3; ++c) { const d = a[i + c] - b[i + c]; se += d * d; px = Math.max(px, Math.abs(d)); }
    if (px > 16) ++differing;
  }
  const mse = se / (3 * w * h);
  const png = gl.toDataURL('image/png');
  return { width: w, height: h, psnr: mse > 0 ? 10 * Math.log10(255 * 255 / mse) : 100, differing: differing / (w * h), png };
});
// The page as a person opens it: the first camera's view, then a drag
// (orbit), a right drag (pan), the wheel (zoom) and a jump to another
// camera, each drawing a new frame.
const interaction = { frames: 0, changed: 0 };
if (interact) {
  const p2 = await browser.newPage({ viewport: { width: 800, height: 600 }, deviceScaleFactor: 1 });
  p2.on('console', (m) => { if (m.type() === 'error') errors.push(`console (interactive): ${m.text()}`); });
  p2.on('pageerror', (e) => errors.push(`exception (interactive): ${e.message}`));
  await p2.goto(`http://127.0.0.1:${port}/index.html`);
  try {
    await p2.waitForFunction(() => window.s2r && (window.s2r.ready || window.s2r.error), null, { timeout, polling: 200 });
    const shot = async () => p2.evaluate(() => document.getElementById('view').toDataURL());
    const frames = async () => p2.evaluate(() => window.s2r.frames);
    let before = await shot();
    const step = async (what, act) => {
      const f0 = await frames();
      await act();
      await p2.waitForFunction((n) => window.s2r.frames > n, f0, { timeout, polling: 100 });
      const now = await shot();
      if (now !== before) interaction.changed += 1;
      else errors.push(`interactive: ${what} drew the same image`);
      before = now;
    };
    await step('drag', async () => { await p2.mouse.move(400, 300); await p2.mouse.down(); await p2.mouse.move(460, 320, { steps: 4 }); await p2.mouse.up(); });
    await step('right drag', async () => { await p2.mouse.move(400, 300); await p2.mouse.down({ button: 'right' }); await p2.mouse.move(430, 280, { steps: 3 }); await p2.mouse.up({ button: 'right' }); });
    await step('wheel', async () => { await p2.mouse.move(400, 300); await p2.mouse.wheel(0, -300); });
    await step('camera', async () => { await p2.selectOption('#cameras', '1'); });
    interaction.frames = await frames();
  } catch (e) {
    errors.push(`interactive: ${e.message}`);
  }
}
await browser.close();
server.close();
if (result.png) fs.writeFileSync(args.out, Buffer.from(result.png.split(',')[1], 'base64'));
delete result.png;
if (state && state.error) errors.push(`viewer: ${state.error}`);
if (result.error) errors.push(result.error);
const ok = errors.length === 0 && state && state.ready && result.psnr >= minPsnr;
console.log(JSON.stringify({ ok, psnr_db: result.psnr, pixels_off_by_more_than_16: result.differing, width: result.width,
  height: result.height, facets_drawn: state?.drawn, frame_ms: state?.frameMs, load_ms: loadMs, interaction, errors }));
process.exit(ok ? 0 : 1);
