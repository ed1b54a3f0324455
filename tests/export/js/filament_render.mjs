// Filament (npm filament 1.53.4, its WASM build) rendering exported KTX1 files in headless Chromium (SwiftShader
// WebGL2, one launch): filament_page.html loads each file with Engine.createIblFromKtx1 / createSkyFromKtx1 and
// renders the request's jobs (skybox, or a glTF sphere lit by the file's IBL, its 'sh' or a constant SH).
// Usage: node filament_render.mjs REQUEST.json  (request: {files: [path.ktx], jobs: [{kind: 'sky'|'sphere',
//        metallic, roughness, ibl: 'ktx'|'sh'|'one', intensity}]}); prints JSON {path: report} on stdout, each
//        report {width, height, views, ups, shfloats, renders: [[base64 RGBA8 per view] per job], consoleErrors}.
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { here, servedChromium } from './served_chromium.mjs';

const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const files = new Map(request.files.map((f, i) => [`/file/${i}.ktx`, f]));
const { port, browser, close } = await servedChromium(
  (url) => (url === '/page.html' ? join(here, 'filament_page.html') : files.get(url) ?? null));
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
  await close();
}
process.stdout.write(JSON.stringify(out));
