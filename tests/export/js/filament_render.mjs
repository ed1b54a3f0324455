// Filament (npm filament 1.53.4, its WASM build) rendering exported KTX1 files in headless Chromium (SwiftShader
// WebGL2, one launch): filament_page.html loads each file with Engine.createIblFromKtx1 / createSkyFromKtx1 and
// renders the request's jobs (skybox, or a glTF sphere lit by the file's IBL, its 'sh' or a constant SH).
// Usage: node filament_render.mjs REQUEST.json  (request: {files: [path.ktx], jobs: [{kind: 'sky'|'sphere',
//        metallic, roughness, ibl: 'ktx'|'sh'|'one', intensity}]}); prints JSON {path: report} on stdout, each
//        report {width, height, views, ups, shfloats, renders: [[base64 RGBA8 per view] per job], consoleErrors}.
import { createServer } from 'node:http';
import { readFileSync, existsSync, statSync } from 'node:fs';
import { extname, join, normalize, resolve, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = dirname(fileURLToPath(import.meta.url));
const modules = resolve(here, '..', '..', 'node_modules');
const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const files = new Map(request.files.map((f, i) => [`/file/${i}.ktx`, f]));
const types = { '.html': 'text/html', '.js': 'text/javascript', '.wasm': 'application/wasm' };

function serve(req, res) {
  const url = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
  let path = null;
  if (url === '/favicon.ico') { res.writeHead(204); res.end(); return; }
  if (url === '/page.html') path = join(here, 'filament_page.html');
  else if (url.startsWith('/node_modules/')) path = join(modules, normalize(url.slice('/node_modules/'.length)));
  else if (files.has(url)) path = files.get(url);
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
         '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
const out = {};
try {
  for (const [url, file] of files) {
    const page = await browser.newPage();
    const messages = [];
    page.on('console', (m) => { if (m.type() === 'error') messages.push(m.text()); });
    page.on('pageerror', (e) => messages.push(String(e)));
    await page.goto(`http://127.0.0.1:${port}/page.html`);
    try {
      out[file] = await page.evaluate(([u, jobs]) => window.filamentRender(u, jobs), [url, request.jobs]);
    } catch (e) { out[file] = { error: String(e).slice(0, 2000) }; }
    out[file].consoleErrors = messages;
    await page.close();
  }
} finally {
  await browser.close();
  server.close();
}
process.stdout.write(JSON.stringify(out));
