// three.js r187 in Node (one process): ObjectLoader parses lightprobes.json and LightProbe.getIrradianceAt evaluates
// each probe at the given normals; KTX2Loader parses the LightProbeGrid atlases (Data3DTexture) and cubes.
// Usage: node three_check.mjs REQUEST.json ({lightprobes: path|null, normals: [[x,y,z]], ktx2: [paths]}).
import { readFileSync } from 'node:fs';
import { ObjectLoader, Vector3, SphericalHarmonics3 } from 'three';
import { KTX2Loader } from 'three/examples/jsm/loaders/KTX2Loader.js';

const request = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const out = { probes: {}, textures: {} };
if (request.lightprobes) {
  const root = new ObjectLoader().parse(JSON.parse(readFileSync(request.lightprobes, 'utf8')));
  root.updateMatrixWorld(true);
  root.traverse((o) => {
    if (!o.isLightProbe) return;
    const p = new Vector3(); o.getWorldPosition(p);
    out.probes[o.name] = { position: [p.x, p.y, p.z], intensity: o.intensity,
      irradiance: request.normals.map(([x, y, z]) => { const t = new Vector3();
        o.sh.getIrradianceAt(new Vector3(x, y, z), t); return [t.x * o.intensity, t.y * o.intensity, t.z * o.intensity]; }) };
  });
}
const loader = new KTX2Loader();
for (const path of request.ktx2 || []) {
  const bytes = readFileSync(path);
  const tex = await loader._createTexture(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength));
  const img = tex.image;
  const entry = { type: tex.constructor.name, isData3DTexture: !!tex.isData3DTexture, width: img.width,
                  height: img.height, depth: img.depth ?? null, dataType: tex.type, format: tex.format };
  if (tex.isData3DTexture && request.grids && request.grids[path]) {
    // unpack the atlas exactly as lightprobes_pars_fragment does at each probe's texel centre, then evaluate with
    // three's own SphericalHarmonics3.getIrradianceAt (the shader's constants)
    const { resolution: [nx, ny, nz], probes } = request.grids[path];
    const data = img.data, padded = nz + 2, at = (x, y, z, c) => data[4 * (x + nx * (y + ny * z)) + c];
    entry.irradiance = {};
    for (const [name, [ix, iy, iz]] of Object.entries(probes)) {
      const f = [];
      for (let t = 0; t < 7; t++) for (let c = 0; c < 4; c++) f.push(at(ix, iy, t * padded + 1 + iz, c));
      const sh = new SphericalHarmonics3().fromArray(f.slice(0, 27));
      entry.irradiance[name] = request.normals.map(([x, y, z]) => { const r = new Vector3();
        sh.getIrradianceAt(new Vector3(x, y, z), r); return [r.x, r.y, r.z]; });
      // padding slices repeat the first/last data slice
      entry.paddingOk = (entry.paddingOk ?? true) && [0, 1, 2, 3].every((c) =>
        at(ix, iy, 0, c) === at(ix, iy, 1, c) && at(ix, iy, padded - 1, c) === at(ix, iy, nz, c));
    }
  }
  out.textures[path] = entry;
}
process.stdout.write(JSON.stringify(out));
