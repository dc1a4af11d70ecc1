// Normals as a renderer draws them (`node --test test/`): three.js's GLTFLoader reads every
// mesh and point GLB of a fuji export (plain and meshopt; TERRASTREAM_BIN as in
// lib/fuji-export.mjs), and each vertex's NORMAL, through the normal matrix three.js lights with
// (the inverse transpose of the node's world matrix), must point where the surface does: the
// area-weighted normal of the vertex's triangles, from the positions as placed (world matrix
// applied), over the triangles of every GLB of the same depth and level at that place (a
// vertex on a tile's border is drawn with the normal of the surface on both sides). A node
// scale that differs per axis (positions on a grid with a finer height step) bends drawn
// normals towards the stretched axis, by tens of degrees on a terrain; normals over a tile's
// own triangles only make lighting seams along tile borders (the two sides drawn apart).
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

// One GLB's mesh vertices as placed: world positions, drawn normals (through the normal
// matrix) and the area-weighted sums of their top triangles; null for a GLB of points (no
// surface; their normals are checked in tests/tiles3d.rs).
function drawnMesh(gltf) {
  let out = null;
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
    const drawn = [];
    for (let i = 0; i < pos.count; i++) drawn.push(new THREE.Vector3().fromBufferAttribute(nrm, i).applyMatrix3(normalMatrix).normalize());
    out = { world, sums, drawn };
  });
  return out;
}

// The place of a vertex on the map (x, −north to the millimetre), per depth and level.
const placeKey = (group, p) => `${group}:${Math.round(p.x * 1000)}:${Math.round(p.z * 1000)}`;

test('drawn normals of a fuji export point where its surfaces do', async (t) => {
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'ts-normals-'));
  try {
    const dirs = fujiExports(tmp, ['none', 'meshopt']);
    for (const [form, dir] of Object.entries(dirs)) {
      const files = fs.readdirSync(dir, { recursive: true }).filter((f) => f.endsWith('.glb'));
      const meshes = [];
      for (const rel of files) {
        const m = drawnMesh(await load(path.join(dir, rel)));
        // tiles/{z}/{x}/{y}/{level}.glb: neighbours are of one z and level.
        const parts = rel.split(path.sep);
        if (m !== null) meshes.push({ ...m, group: `${parts.at(-4)}/${parts.at(-1)}` });
      }
      const surface = new Map();
      for (const m of meshes) {
        m.world.forEach((p, i) => {
          const k = placeKey(m.group, p);
          surface.set(k, (surface.get(k) ?? new THREE.Vector3()).add(m.sums[i]));
        });
      }
      let worst = 0, seam = 0, shared = 0;
      const seen = new Map();
      for (const m of meshes) {
        m.world.forEach((p, i) => {
          if (m.sums[i].lengthSq() === 0) return;
          const k = placeKey(m.group, p);
          worst = Math.max(worst, THREE.MathUtils.radToDeg(m.drawn[i].angleTo(surface.get(k).clone().normalize())));
          const other = seen.get(k);
          if (other === undefined) seen.set(k, { m, d: m.drawn[i] });
          else if (other.m !== m) {
            shared++;
            seam = Math.max(seam, THREE.MathUtils.radToDeg(other.d.angleTo(m.drawn[i])));
          }
        });
      }
      t.diagnostic(`${form}: ${files.length} GLBs, ${meshes.length} meshes, largest drawn-normal angle ${worst.toFixed(2)}°, ` +
        `${shared} border vertices two tiles draw, largest angle between their normals ${seam.toFixed(2)}°`);
      assert.ok(meshes.length >= 5, `${form}: ${meshes.length} meshes`);
      assert.ok(shared >= 100, `${form}: ${shared} shared border vertices`);
      assert.ok(worst < 5, `${form}: a drawn normal ${worst.toFixed(1)}° off its surface`);
      assert.ok(seam < 2, `${form}: neighbours draw a shared vertex ${seam.toFixed(1)}° apart (a lighting seam)`);
    }
  } finally {
    fs.rmSync(tmp, { recursive: true, force: true });
  }
});
