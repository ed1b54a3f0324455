// Babylon.js in headless Chromium (one browser launch): loads exported glTF assets with Babylon's own glTF loader and
// EXT_lights_image_based, reports its spherical harmonics, the read-back cube texels and (optionally) a screenshot.
// Usage: node babylon_check.mjs REQUEST.json  (request: {root, assets: [path relative to root], normals: [[x,y,z]],
//        screenshot: {asset, path} | null}); prints JSON {asset: report} on stdout.
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { here, servedChromium, under } from './served_chromium.mjs';

const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const { port, browser, close } = await servedChromium(
  (url) => (url === '/page.html' ? join(here, 'babylon_page.html') : under(url, '/export/', request.root)), { srgb: true });
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
  await close();
}
process.stdout.write(JSON.stringify(out));
