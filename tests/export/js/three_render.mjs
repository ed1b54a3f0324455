// three.js r187 (WebGLRenderer, SwiftShader WebGL2 in headless Chromium, one launch) rendering a bakery `three`
// export: three_render_page.html renders each requested job into a float render target (linear output, no tone
// mapping) and returns the float pixels.
// Usage: node three_render.mjs REQUEST.json
//   request: {root: folder, loader: path of the cube loader snippet (docs/exports.md, served as /loader.js),
//             cubes: {key: cube file}, lightprobes: file | null, grids: lightprobegrids.json | null (paths under root),
//             size: pixels, jobs: [...] (three_render_page.html)}
//   prints JSON {width, height, views, ups, renders: [[base64 float32 RGBA per view] per job], info, consoleErrors}.
import { createServer } from 'node:http';
import { readFileSync, existsSync, statSync } from 'node:fs';
import { extname, join, normalize, resolve, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = dirname(fileURLToPath(import.meta.url));
const modules = resolve(here, '..', '..', 'node_modules');
const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const types = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript',
                '.json': 'application/json', '.wasm': 'application/wasm' };

function serve(req, res) {
  const url = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
  let path = null;
  if (url === '/favicon.ico') { res.writeHead(204); res.end(); return; }
  if (url === '/page.html') path = join(here, 'three_render_page.html');
  else if (url === '/loader.js') path = request.loader;
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
         '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
let out;
try {
  const page = await browser.newPage();
  const messages = [];
  page.on('console', (m) => { if (m.type() === 'error' || m.type() === 'warning') messages.push(`${m.type()}: ${m.text()}`); });
  page.on('pageerror', (e) => messages.push(String(e)));
  await page.goto(`http://127.0.0.1:${port}/page.html`);
  try {
    await page.waitForFunction(() => window.bakeryThreeRender !== undefined, null, { timeout: 60000 });
    out = await page.evaluate((r) => window.bakeryThreeRender(r), request);
  } catch (e) { out = { error: `${String(e).slice(0, 3000)} ${messages.join(' | ')}` }; }
  out.consoleErrors = messages;
  await page.close();
} finally {
  await browser.close();
  server.close();
}
process.stdout.write(JSON.stringify(out));
