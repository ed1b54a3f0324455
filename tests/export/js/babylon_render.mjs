// Babylon.js rendering exported glTF assets in headless Chromium (SwiftShader WebGL2, one launch): for each asset
// and each scene handedness requested, babylon_render_page.html renders its EXT_lights_image_based light as a
// skybox, on a mirror sphere and on a rough sphere.
// Usage: node babylon_render.mjs REQUEST.json  (request: {root, assets: [path relative to root], rightHanded:
//        [false, true]}); prints JSON {asset: {"false"|"true": report}} on stdout.
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
  if (url === '/page.html') path = join(here, 'babylon_render_page.html');
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
    out[asset] = {};
    for (const rightHanded of request.rightHanded) {
      const page = await browser.newPage();
      const messages = [];
      page.on('console', (m) => { if (m.type() === 'error') messages.push(m.text()); });
      page.on('pageerror', (e) => messages.push(String(e)));
      await page.goto(`http://127.0.0.1:${port}/page.html`);
      let report;
      try {
        report = await page.evaluate(([a, h]) => window.bakeryRender(a, h), [`/export/${asset}`, rightHanded]);
      } catch (e) { report = { error: String(e).slice(0, 2000) }; }
      report.consoleErrors = messages;
      out[asset][String(rightHanded)] = report;
      await page.close();
    }
  }
} finally {
  await browser.close();
  server.close();
}
process.stdout.write(JSON.stringify(out));
