// three.js r187 (WebGLRenderer on SwiftShader WebGL2, or WebGPURenderer on SwiftShader WebGPU; headless Chromium,
// one launch) rendering a bakery `three` export: three_render_page.html renders each requested job into a float
// render target (linear output, no tone mapping) and returns the float pixels.
// Usage: node three_render.mjs REQUEST.json
//   request: {root: folder, loader: path of the cube loader snippet (docs/exports.md, served as /loader.js),
//             cubes: {key: cube file}, lightprobes: file | null, grids: lightprobegrids.json | null (paths under root),
//             size: pixels, jobs: [...] (three_render_page.html), renderer: 'webgl' (default) | 'webgpu'}
//   prints JSON {width, height, views, ups, renders: [[base64 float32 RGBA per view] per job], info, consoleErrors}.
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { here, servedChromium, under } from './served_chromium.mjs';

const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const { port, browser, close } = await servedChromium((url) => (
  url === '/page.html' ? join(here, 'three_render_page.html')
    : url === '/loader.js' ? request.loader : under(url, '/export/', request.root)),
  { webgpu: request.renderer === 'webgpu' });
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
  await close();
}
process.stdout.write(JSON.stringify(out));
