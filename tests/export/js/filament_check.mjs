// Filament (npm filament, its WASM build) in Node: Ktx1Bundle parses each exported KTX1 cube and its 'sh' metadata;
// IndirectLight.getDirectionEstimate / getColorEstimate run on the 27 floats.
// Usage: node filament_check.mjs FILE.ktx ...
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { dirname } from 'node:path';
import vm from 'node:vm';

// filament.js is written for a browser global: Filament.init() replaces the global `Filament` by the loaded
// module. Run it as a classic script in this context (with the CommonJS globals its Node path needs).
const require = createRequire(import.meta.url);
const path = require.resolve('filament');
Object.assign(globalThis, { require, __filename: path, __dirname: dirname(path) });
vm.runInThisContext(readFileSync(path, 'utf8'), { filename: path });
await new Promise((ok) => globalThis.Filament.init([], ok));
const Filament = globalThis.Filament;
const out = {};
for (const file of process.argv.slice(2)) {
  try {
    const bytes = new Uint8Array(readFileSync(file));
    const buffer = Filament.Buffer(bytes);  // a driver$BufferDescriptor, as Engine.createIblFromKtx1 makes
    const ktx = new Filament.Ktx1Bundle(buffer);
    buffer.delete();
    const info = ktx.info();
    const shText = ktx.getMetadata('sh');
    const sh = shText.split(/\s/, 9 * 3).map(parseFloat);
    const dir = Filament.IndirectLight.getDirectionEstimate(sh);
    const colour = Filament.IndirectLight.getColorEstimate(sh, dir);
    out[file] = { ok: true, isCubemap: ktx.isCubemap(), levels: ktx.getNumMipLevels(), arrayLength: ktx.getArrayLength(),
                  glInternalFormat: info.glInternalFormat, glType: info.glType, pixelWidth: info.pixelWidth,
                  sh, direction: Array.from(dir), colour: Array.from(colour),
                  cubeBlobBytes: Array.from({ length: ktx.getNumMipLevels() }, (_, i) => ktx.getCubeBlob(i).length) };
    ktx.delete();
  } catch (e) { out[file] = { ok: false, error: String(e?.message ?? e).slice(0, 300) }; }
}
process.stdout.write(JSON.stringify(out));
