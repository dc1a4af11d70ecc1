// Normals as a renderer draws them (`node --test test/`): three.js's GLTFLoader reads every
// mesh and point GLB of a fuji export (plain and meshopt; TERRASTREAM_BIN as in
// lib/fuji-export.mjs), and each vertex's NORMAL, through the normal matrix three.js lights with
// (the inverse transpose of the node's world matrix), must point where the surface does: the
// area-weighted normal of the vertex's triangles, from the positions as placed (world matrix
// applied). A node scale that differs per axis (positions on a grid with a finer height step)
// bends drawn normals towards the stretched axis, by tens of degrees on a terrain.
import test from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'meshoptimizer';
import { fujiExports } from '../lib/fuji-export.mjs';

const loader = new GLTFLoader();
loader.setMeshoptDecoder(MeshoptDecoder);

function load(file) {
  const buf = fs.readFileSync(file);
  const ab = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
  return new Promise((resolve, reject) => loader.parse(ab, '', resolve, reject));
}

// Largest angle (degrees) between a drawn normal and its surface's over one GLB's mesh
// vertices; null for a GLB of points (no surface; their normals are checked in tests/tiles3d.rs).
function worstAngle(gltf) {
  let worst = null;
  gltf.scene.updateMatrixWorld(true);
  gltf.scene.traverse((o) => {
    if (!o.isMesh) return;
    const g = o.geometry;
    const pos = g.getAttribute('position'), nrm = g.getAttribute('normal');
    const normalMatrix = new THREE.Matrix3().getNormalMatrix(o.matrixWorld);
    const world = [];
    for (let i = 0; i < pos.count; i++) world.push(new THREE.Vector3().fromBufferAttribute(pos, i).applyMatrix4(o.matrixWorld));
    const sums = world.map(() => new THREE.Vector3());
    const idx = g.index;
    const ab = new THREE.Vector3(), ac = new THREE.Vector3();
    for (let t = 0; t + 2 < idx.count; t += 3) {
      const [a, b, c] = [idx.getX(t), idx.getX(t + 1), idx.getX(t + 2)];
      ab.subVectors(world[b], world[a]);
      ac.subVectors(world[c], world[a]);
      const n = new THREE.Vector3().crossVectors(ab, ac);
      // Skirt walls hang straight down from the border (a vertical face: no y, glTF's up);
      // their vertices take the normal of the surface above them, left out here.
      if (Math.abs(n.y) <= 1e-9 * n.length()) continue;
      sums[a].add(n); sums[b].add(n); sums[c].add(n);
    }
    for (let i = 0; i < pos.count; i++) {
      if (sums[i].lengthSq() === 0) continue;
      const drawn = new THREE.Vector3().fromBufferAttribute(nrm, i).applyMatrix3(normalMatrix).normalize();
      const deg = THREE.MathUtils.radToDeg(drawn.angleTo(sums[i].normalize()));
      worst = Math.max(worst ?? 0, deg);
    }
  });
  return worst;
}

test('drawn normals of a fuji export point where its surfaces do', async (t) => {
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'ts-normals-'));
  try {
    const dirs = fujiExports(tmp, ['none', 'meshopt']);
    for (const [form, dir] of Object.entries(dirs)) {
      const files = fs.readdirSync(dir, { recursive: true }).filter((f) => f.endsWith('.glb'));
      let meshes = 0, worst = 0;
      for (const rel of files) {
        const w = worstAngle(await load(path.join(dir, rel)));
        if (w === null) continue;
        meshes++;
        worst = Math.max(worst, w);
      }
      t.diagnostic(`${form}: ${files.length} GLBs, ${meshes} meshes, largest drawn-normal angle ${worst.toFixed(2)}°`);
      assert.ok(meshes >= 5, `${form}: ${meshes} meshes`);
      assert.ok(worst < 5, `${form}: a drawn normal ${worst.toFixed(1)}° off its surface`);
    }
  } finally {
    fs.rmSync(tmp, { recursive: true, force: true });
  }
});
