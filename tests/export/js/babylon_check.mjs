// Babylon.js in headless Chromium (one browser launch): loads exported glTF assets with Babylon's own glTF loader and
// EXT_lights_image_based, reports its spherical harmonics, the read-back cube texels and (optionally) a screenshot.
// Usage: node babylon_check.mjs REQUEST.json  (request: {root, assets: [path relative to root], normals: [[x,y,z]],
//        screenshot: {asset, path} | null}); prints JSON {asset: report} on stdout.
import { createServer } from 'node:http';
import { readFileSync, existsSync, statSync } from 'node:fs';
import { extname, join, normalize, resolve, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = dirname(fileURLToPath(import.meta.url));
const modules = resolve(here, '..', '..', 'node_modules');
const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const types = { '.html': 'text/html', '.js': 'text/javascript', '.gltf': 'model/gltf+json', '.png': 'image/png',
                '.json': 'application/json', '.wasm': 'application/wasm' };

function serve(req, res) {
  const url = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
  let path = null;
  if (url === '/favicon.ico') { res.writeHead(204); res.end(); return; }
  if (url === '/page.html') path = join(here, 'babylon_page.html');
  else if (url.startsWith('/node_modules/')) path = join(modules, normalize(url.slice('/node_modules/'.length)));
  else if (url.startsWith('/export/')) path = join(request.root, normalize(url.slice('/export/'.length)));
  if (!path || !existsSync(path) || !statSync(path).isFile()) { res.writeHead(404); res.end(); return; }
  res.writeHead(200, { 'Content-Type': types[extname(path)] || 'application/octet-stream' });
  res.end(readFileSync(path));
}

const server = createServer(serve);
await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
const port = server.address().port;
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium', headless: true,
  args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
         '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
         '--force-color-profile=srgb'],
});
const out = {};
try {
  for (const asset of request.assets) {
    const page = await browser.newPage({ viewport: { width: 640, height: 360 } });
    const messages = [];
    page.on('console', (m) => { if (m.type() === 'error') messages.push(m.text()); });
    page.on('pageerror', (e) => messages.push(String(e)));
    await page.goto(`http://127.0.0.1:${port}/page.html`);
    const shot = request.screenshot && request.screenshot.asset === asset;
    try {
      out[asset] = await page.evaluate(([a, n, r]) => window.bakeryCheck(a, n, r), [`/export/${asset}`, request.normals, !!shot]);
      if (shot) await page.locator('canvas').screenshot({ path: request.screenshot.path });
    } catch (e) { out[asset] = { error: String(e) }; }
    out[asset].consoleErrors = messages;
    await page.close();
  }
} finally {
  await browser.close();
  server.close();
}
process.stdout.write(JSON.stringify(out));
