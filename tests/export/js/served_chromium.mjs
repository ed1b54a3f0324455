// The page server and headless Chromium (SwiftShader WebGL2) shared by the consumer scripts: a local HTTP server for
// the script's page, tests/node_modules and the files its request names, and one browser launch.
// Usage: const { port, browser, close } = await servedChromium((url) => path | null, { srgb: true });
import { createServer } from 'node:http';
import { readFileSync, existsSync, statSync } from 'node:fs';
import { extname, join, normalize, resolve, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

export const here = dirname(fileURLToPath(import.meta.url));
const modules = resolve(here, '..', '..', 'node_modules');
const types = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.json': 'application/json',
                '.gltf': 'model/gltf+json', '.png': 'image/png', '.wasm': 'application/wasm' };

/** Below `prefix` of the URL path, the file under `root` (null outside it). */
export function under(url, prefix, root) {
  return url.startsWith(prefix) ? join(root, normalize(url.slice(prefix.length))) : null;
}

/** Serve `route(urlPath)` (a file path or null) and /node_modules/, then launch Chromium. `srgb`: force the sRGB
 * colour profile (screenshots); `webgpu`: WebGPU on SwiftShader's Vulkan (the GPU process kept: no --disable-gpu).
 * Returns {port, browser, close}. */
export async function servedChromium(route, { srgb = false, webgpu = false } = {}) {
  const server = createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
    if (url === '/favicon.ico') { res.writeHead(204); res.end(); return; }
    const path = route(url) ?? under(url, '/node_modules/', modules);
    if (!path || !existsSync(path) || !statSync(path).isFile()) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'Content-Type': types[extname(path)] || 'application/octet-stream' });
    res.end(readFileSync(path));
  });
  await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium', headless: true,
    args: ['--no-sandbox',
           ...(webgpu ? ['--enable-unsafe-webgpu', '--enable-features=Vulkan', '--use-webgpu-adapter=swiftshader']
             : ['--disable-gpu']),
           '--disable-quic', '--no-first-run', '--disable-background-networking',
           '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
           ...(srgb ? ['--force-color-profile=srgb'] : [])],
  });
  return { port: server.address().port, browser, close: async () => { await browser.close(); server.close(); } };
}
