// EXT_meshopt_compression GLBs against meshoptimizer's own decoder (`node --test test/`): bakes
// fuji.png with the binary under test (TERRASTREAM_BIN, default ../../target/release/terrastream),
// exports it as 3D Tiles plain and with --glb-compression meshopt, and decodes every meshopt GLB
// with MeshoptDecoder to the plain GLB's mesh (see lib/meshopt-checks.mjs: positions exact,
// normals, through the OCTAHEDRAL filter, within 2°); the Khronos validator finds no error or
// warning (it reports the extension as unsupported, an info).
import test from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import validator from 'gltf-validator';
import { compareTrees } from '../lib/meshopt-checks.mjs';
import { fujiExports } from '../lib/fuji-export.mjs';

test('meshopt GLBs of a fuji export decode (MeshoptDecoder) to the plain GLBs', async (t) => {
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'ts-meshopt-'));
  try {
    const dirs = fujiExports(tmp, ['none', 'meshopt']);
    const r = await compareTrees(dirs.none, dirs.meshopt);
    t.diagnostic(`${r.glbs} GLBs: meshopt ${r.meshopt} bytes, plain ${r.plain}; largest normal angle to the plain GLB's ${r.maxDeg.toFixed(3)}°`);
    assert.ok(r.glbs >= 10, `${r.glbs} GLBs`);
    assert.ok(r.meshopt < r.plain / 2, `meshopt ${r.meshopt} bytes vs plain ${r.plain}`);
    // The Khronos validator does not know the extension: it must report it as unsupported (an
    // info) and find no error or warning in the rest.
    for (const rel of ['tiles/0/0/0/0.glb', 'tiles/0/0/0/3.glb']) {
      const v = await validator.validateBytes(new Uint8Array(fs.readFileSync(path.join(dirs.meshopt, rel))), { maxIssues: 50 });
      assert.equal(v.issues.numErrors + v.issues.numWarnings, 0, `${rel}: ${JSON.stringify(v.issues.messages)}`);
      assert.ok(v.issues.messages.some((m) => m.code === 'UNSUPPORTED_EXTENSION' && m.message.includes('EXT_meshopt_compression')), rel);
    }
  } finally {
    fs.rmSync(tmp, { recursive: true, force: true });
  }
});
