// Babylon.js rendering exported glTF assets in headless Chromium (SwiftShader WebGL2, one launch): for each asset
// and each scene handedness requested, babylon_render_page.html renders its EXT_lights_image_based light as a
// skybox, on a mirror sphere and on a rough sphere.
// Usage: node babylon_render.mjs REQUEST.json  (request: {root, assets: [path relative to root], rightHanded:
//        [false, true]}); prints JSON {asset: {"false"|"true": report}} on stdout.
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { here, servedChromium, under } from './served_chromium.mjs';

const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const { port, browser, close } = await servedChromium(
  (url) => (url === '/page.html' ? join(here, 'babylon_render_page.html') : under(url, '/export/', request.root)), { srgb: true });
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
  await close();
}
process.stdout.write(JSON.stringify(out));
