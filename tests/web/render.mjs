// Renders a GLB with three.js in headless Chromium (Debian's /usr/bin/chromium, driven by
// playwright-core) and writes the linear float picture.
// Usage: node render.mjs scene.glb out.json --width 64 --height 64 [--mode lightmap|emissive]
//        [--camera /World/Camera] [--png shot.png --exposure 1] [--specular]
// out.json: {"width", "height", "rgb": [row-major top-down RGB floats], "stats": {...}}
import { createServer } from 'node:http';
import { readFileSync, writeFileSync, renameSync, mkdtempSync, rmSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, dirname, extname, resolve, normalize } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = dirname(fileURLToPath(import.meta.url));
const args = process.argv.slice(2);
const opt = (name, dflt) => { const i = args.indexOf(name); return i >= 0 ? args[i + 1] : dflt; };
const [glb, outPath] = args;
if (!glb || !outPath) { console.error('usage: node render.mjs scene.glb out.json [options]'); process.exit(2); }
const width = Number(opt('--width', 64)), height = Number(opt('--height', 64));
const types = { '.html': 'text/html', '.mjs': 'text/javascript', '.js': 'text/javascript', '.glb': 'model/gltf-binary' };

// A static server on loopback for the page, three.js and the GLB (module scripts need http).
const server = createServer((req, res) => {
  const path = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  const file = path === '/scene.glb' ? resolve(glb) : normalize(join(here, path));
  if (!(path === '/scene.glb' || file.startsWith(here)) || !existsSync(file)) { res.writeHead(404); res.end(); return; }
  res.writeHead(200, { 'content-type': types[extname(file)] || 'application/octet-stream' });
  res.end(readFileSync(file));
});
await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
const port = server.address().port;
const profile = mkdtempSync(join(tmpdir(), 'hirad-chromium-'));
// A fresh profile each run (playwright passes it as --user-data-dir); no GPU here, so WebGL
// runs on SwiftShader, Chromium's software renderer.
const browser = await chromium.launchPersistentContext(profile, {
  executablePath: process.env.HIRAD_CHROMIUM || '/usr/bin/chromium',
  headless: true,
  viewport: { width, height },
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync',
    '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
let code = 0;
try {
  const page = browser.pages()[0] || await browser.newPage();
  const logs = [];
  page.on('console', (m) => logs.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
  await page.goto(`http://127.0.0.1:${port}/render.html`);
  await page.waitForFunction(() => window.hiradReady === true, null, { timeout: 30000 });
  const result = await page.evaluate((o) => window.hiradRender(o), {
    url: '/scene.glb', width, height, mode: opt('--mode', 'lightmap'), camera: opt('--camera', null),
    lambertian: !args.includes('--specular'), exposure: Number(opt('--exposure', 1)),
  });
  const png = opt('--png', null);
  if (png) {
    await page.locator('canvas').screenshot({ path: png + '.partial.png' });
    renameSync(png + '.partial.png', png);
  }
  result.stats.console = logs;
  writeFileSync(outPath + '.partial', JSON.stringify({ width, height, ...result }));
  renameSync(outPath + '.partial', outPath);
} catch (e) {
  console.error(String(e && e.stack || e));
  code = 1;
} finally {
  await browser.close();
  server.close();
  rmSync(profile, { recursive: true, force: true });
}
process.exit(code);
