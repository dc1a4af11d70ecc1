// KHR_draco_mesh_compression GLBs against Google's own Draco decoder (`node --test test/`): bakes
// fuji.png with the binary under test (TERRASTREAM_BIN, default ../../target/release/terrastream),
// exports it as 3D Tiles plain, with --glb-compression draco and with --glb-compression meshopt;
// decodes every mesh GLB of the draco export with draco3d (npm `draco3d`) and every point GLB
// (EXT_meshopt_compression there) with MeshoptDecoder to the plain GLB's mesh (see
// lib/draco-checks.mjs); the draco export must be smaller than the meshopt one. The Khronos
// validator finds no error or warning in a Draco mesh GLB (it reports the extension as
// unsupported, and the Draco stream's buffer view, which only the extension names, as maybe
// unused: two infos).
import test from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import validator from 'gltf-validator';
import { compareDracoTrees, EXT } from '../lib/draco-checks.mjs';
import { glbFiles, readGlb } from '../lib/meshopt-checks.mjs';
import { fujiExports } from '../lib/fuji-export.mjs';

test('draco GLBs of a fuji export decode (draco3d; MeshoptDecoder for points) to the plain GLBs', async (t) => {
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'ts-draco-'));
  try {
    const dirs = fujiExports(tmp, ['none', 'draco', 'meshopt']);
    dirs.plain = dirs.none;
    const r = await compareDracoTrees(dirs.plain, dirs.draco);
    const meshopt = glbFiles(dirs.meshopt).reduce((n, rel) => n + fs.statSync(path.join(dirs.meshopt, rel)).size, 0);
    t.diagnostic(`${r.glbs} GLBs (${r.meshes} Draco meshes, ${r.points} meshopt points): draco ${r.draco} bytes, meshopt ${meshopt}, plain ${r.plain}`);
    t.diagnostic(`largest normal angle to the plain GLB's: ${r.maxDeg.mesh.toFixed(3)}° (Draco meshes), ${r.maxDeg.points.toFixed(3)}° (meshopt points)`);
    assert.ok(r.glbs >= 10, `${r.glbs} GLBs`);
    assert.ok(r.meshes >= 1 && r.points >= 1, `${r.meshes} mesh GLBs, ${r.points} point GLBs: this bake should give both`);
    assert.ok(r.draco < meshopt, `draco ${r.draco} bytes vs meshopt ${meshopt}`);

    // The Khronos validator does not know the extension: it must report it as unsupported and
    // the Draco buffer view as maybe unused (infos), and find no error or warning in the rest;
    // its vertex and triangle counts (the accessors') are the plain GLB's.
    const rel = 'tiles/0/0/0/0.glb';
    const bytes = fs.readFileSync(path.join(dirs.draco, rel));
    const { json } = readGlb(bytes);
    const dracoView = json.meshes[0].primitives[0].extensions?.[EXT]?.bufferView;
    assert.notEqual(dracoView, undefined, `${rel} is not a Draco mesh GLB`);
    const v = await validator.validateBytes(new Uint8Array(bytes), { maxIssues: 50 });
    const plain = await validator.validateBytes(new Uint8Array(fs.readFileSync(path.join(dirs.plain, rel))), { maxIssues: 50 });
    t.diagnostic(`gltf-validator on ${rel}: ${JSON.stringify(v.issues.messages)}`);
    assert.equal(v.issues.numErrors + v.issues.numWarnings, 0, `${rel}: ${JSON.stringify(v.issues.messages)}`);
    const expected = [
      `UNSUPPORTED_EXTENSION /extensionsUsed/${json.extensionsUsed.indexOf(EXT)} ${EXT}`,
      `UNUSED_OBJECT /bufferViews/${dracoView}`,
    ];
    const got = v.issues.messages.map((m) => `${m.code} ${m.pointer}${m.code === 'UNSUPPORTED_EXTENSION' ? ` ${m.message.match(/'([^']+)'/)?.[1]}` : ''}`);
    assert.deepEqual(got.sort(), expected.sort(), `${rel}: ${JSON.stringify(v.issues.messages)}`);
    assert.ok(v.issues.messages.every((m) => m.severity === 2), `${rel}: not all infos`);
    for (const k of ['totalVertexCount', 'totalTriangleCount', 'drawCallCount']) assert.equal(v.info[k], plain.info[k], `${rel}: ${k}`);
  } finally {
    fs.rmSync(tmp, { recursive: true, force: true });
  }
});
