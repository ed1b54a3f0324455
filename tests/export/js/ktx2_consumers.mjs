// KTX2 consumers, one Node process: ktx-parse (read every field, re-serialise), KTX-Software's libktx (WASM build
// shipped in @khronosgroup/gltf-viewer) and three.js r187 KTX2Loader.
// Usage: node ktx2_consumers.mjs FILE... ; prints one JSON object {file: report} on stdout.
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { read, write } from 'ktx-parse';
import { KTX2Loader } from 'three/examples/jsm/loaders/KTX2Loader.js';

const require = createRequire(import.meta.url);
// libktx.js is an Emscripten CommonJS/UMD script inside an ES-module package: evaluate it as CommonJS.
function loadLibktx() {
  const path = require.resolve('@khronosgroup/gltf-viewer/dist/libs/libktx.js');
  const mod = { exports: {} };
  const source = readFileSync(path, 'utf8');
  new Function('module', 'exports', 'require', '__filename', '__dirname', source)(
    mod, mod.exports, require, path, path.slice(0, path.lastIndexOf('/')));
  return mod.exports;
}
const LIBKTX = loadLibktx();

function hex(bytes) { return Buffer.from(bytes).toString('hex'); }

async function main() {
  const libktx = await LIBKTX({ print: () => {}, printErr: () => {} });
  const loader = new KTX2Loader();
  const out = {};
  for (const file of process.argv.slice(2)) {
    const bytes = new Uint8Array(readFileSync(file));
    const report = {};
    // ---- ktx-parse
    try {
      const c = read(bytes);
      const dfd = c.dataFormatDescriptor[0];
      const keyValue = {};
      for (const [k, v] of Object.entries(c.keyValue)) keyValue[k] = typeof v === 'string' ? v : hex(v);
      report.ktxParse = {
        vkFormat: c.vkFormat, typeSize: c.typeSize, pixelWidth: c.pixelWidth, pixelHeight: c.pixelHeight,
        pixelDepth: c.pixelDepth, layerCount: c.layerCount, faceCount: c.faceCount, levelCount: c.levelCount,
        supercompressionScheme: c.supercompressionScheme,
        levels: c.levels.map((l) => ({ byteLength: l.levelData.byteLength, uncompressed: l.uncompressedByteLength,
                                       sha: hex(l.levelData.slice(0, 16)) })),
        dfd: { vendorId: dfd.vendorId, descriptorType: dfd.descriptorType, versionNumber: dfd.versionNumber,
               colorModel: dfd.colorModel, colorPrimaries: dfd.colorPrimaries,
               transferFunction: dfd.transferFunction, flags: dfd.flags,
               texelBlockDimension: dfd.texelBlockDimension, bytesPlane: dfd.bytesPlane,
               samples: dfd.samples.map((s) => ({ bitOffset: s.bitOffset, bitLength: s.bitLength,
                                                 channelType: s.channelType, samplePosition: s.samplePosition,
                                                 sampleLower: s.sampleLower, sampleUpper: s.sampleUpper })) },
        keyValue,
      };
      const again = write(c, { keepWriter: true });
      report.ktxParse.reserialisedIdentical = again.length === bytes.length && Buffer.compare(Buffer.from(again), Buffer.from(bytes)) === 0;
      // first float of level 0 (as a cross-check of the data the reader hands out)
      const l0 = c.levels[0].levelData;
      report.ktxParse.level0Head = Array.from(new Uint8Array(l0.buffer, l0.byteOffset, Math.min(32, l0.byteLength)));
    } catch (e) { report.ktxParse = { error: String(e) }; }
    // ---- libktx
    try {
      const t = new libktx.ktxTexture(bytes);
      report.libktx = { ok: true, baseWidth: t.baseWidth, baseHeight: t.baseHeight, vkFormat: t.vkFormat,
                        numComponents: t.numComponents, needsTranscoding: t.needsTranscoding,
                        orientation: t.orientation ? { x: t.orientation.x?.value ?? String(t.orientation.x),
                                                       y: t.orientation.y?.value ?? String(t.orientation.y) } : null };
      t.delete?.();
    } catch (e) { report.libktx = { ok: false, error: String(e?.message ?? e) }; }
    // ---- three.js KTX2Loader (raw formats need no transcoder)
    try {
      const buffer = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
      const tex = await loader._createTexture(buffer);
      const img = tex.image;
      report.three = { ok: true, type: tex.constructor.name, isData3DTexture: !!tex.isData3DTexture,
                       width: img.width, height: img.height, depth: img.depth ?? null,
                       mipmaps: (tex.mipmaps || []).map((m) => ({ width: m.width, height: m.height,
                                                                 depth: m.depth, length: m.data.length })),
                       dataType: tex.type, format: tex.format, colorSpace: tex.colorSpace,
                       first: Array.from((tex.mipmaps?.[0]?.data ?? img.data).slice(0, 8)) };
    } catch (e) { report.three = { ok: false, error: String(e?.message ?? e) }; }
    out[file] = report;
  }
  process.stdout.write(JSON.stringify(out));
}
main().catch((e) => { console.error(e); process.exit(1); });
