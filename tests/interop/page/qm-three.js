// 3DTilesRendererJS (three.js) with its QuantizedMeshPlugin on a terrastream terrain. run.mjs:
//   await qmThreeLoad(terrainUrl, {lon, lat, h, range}, ms, accept) -> tiles loaded / failed, levels
// terrainUrl is the folder that holds layer.json (…/tilesets/NAME/terrain/). The camera looks
// straight down on (lon, lat, h) from `range` metres; the renderer refines until nothing is
// left to load (tiles-load-end, then quiet for 600 ms) or `ms` has passed. `accept` (a
// diagnosis only): the Accept header of the tile requests instead of the plugin's own.
import * as THREE from 'three';
import { TilesRenderer } from '3d-tiles-renderer';
import { QuantizedMeshPlugin } from '3d-tiles-renderer/plugins';

const errors = [];
window.addEventListener('error', (e) => errors.push(String(e.message)));
window.addEventListener('unhandledrejection', (e) => errors.push(String((e.reason && (e.reason.stack || e.reason)) || e)));

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

window.qmThreeLoad = async function qmThreeLoad(terrainUrl, view, ms, accept) {
  const started = performance.now();
  const renderer = new THREE.WebGLRenderer({ antialias: false, logarithmicDepthBuffer: true, preserveDrawingBuffer: true });
  renderer.setSize(window.innerWidth, window.innerHeight);
  document.body.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.add(new THREE.AmbientLight(0xffffff, 0.6));
  const sun = new THREE.DirectionalLight(0xffffff, 2);
  scene.add(sun);
  const camera = new THREE.PerspectiveCamera(60, window.innerWidth / window.innerHeight, 1, 4e7);

  const tiles = new TilesRenderer(terrainUrl);
  tiles.registerPlugin(new QuantizedMeshPlugin({}));
  scene.add(tiles.group);
  const loaded = [];
  const failed = [];
  let loadEnd = 0;
  tiles.addEventListener('load-model', (e) => loaded.push({ url: String(e.url), vertices: countVertices(e.scene) }));
  tiles.addEventListener('load-error', (e) => failed.push(`${e.url}: ${String((e.error && e.error.message) || e.error)}`));
  tiles.addEventListener('tiles-load-end', () => loadEnd++);
  let pluginAccept = null;
  tiles.addEventListener('load-root-tileset', () => {
    // the plugin has set its Accept (with layer.json's extensions) by now
    pluginAccept = tiles.fetchOptions.headers && tiles.fetchOptions.headers.Accept;
    if (accept) tiles.fetchOptions.headers.Accept = accept;
  });

  // ECEF (tiles.group carries the ellipsoid frame, untransformed): look down on the point
  const target = new THREE.Vector3();
  const eye = new THREE.Vector3();
  const up = new THREE.Vector3();
  const rad = Math.PI / 180;
  tiles.ellipsoid.getCartographicToPosition(view.lat * rad, view.lon * rad, view.h, target);
  tiles.ellipsoid.getCartographicToPosition(view.lat * rad, view.lon * rad, view.h + view.range, eye);
  tiles.ellipsoid.getCartographicToNormal(view.lat * rad, view.lon * rad, up);
  camera.position.copy(eye);
  // "up" on screen: north (the local north vector at the point)
  const north = new THREE.Vector3(-Math.sin(view.lat * rad) * Math.cos(view.lon * rad), -Math.sin(view.lat * rad) * Math.sin(view.lon * rad), Math.cos(view.lat * rad));
  camera.up.copy(north);
  camera.lookAt(target);
  sun.position.copy(eye);
  camera.updateMatrixWorld();
  tiles.setCamera(camera);
  tiles.setResolutionFromRenderer(camera, renderer);

  let quietSince = null;
  let settled = false;
  while (performance.now() - started < ms) {
    camera.updateMatrixWorld();
    tiles.update();
    renderer.render(scene, camera);
    await sleep(50);
    const s = tiles.stats;
    const busy = s.queued + s.downloading + s.parsing > 0;
    if (!busy && loadEnd > 0 && loaded.length > 0) {
      quietSince = quietSince || performance.now();
      if (performance.now() - quietSince > 600) {
        settled = true;
        break;
      }
    } else quietSince = null;
  }
  const levels = {};
  for (const l of loaded) {
    const m = /\/terrain\/(\d+)\/(\d+)\/(\d+)\.terrain/.exec(l.url);
    const key = m ? m[1] : 'split';
    levels[key] = (levels[key] || 0) + 1;
  }
  return {
    settled,
    ms: Math.round(performance.now() - started),
    pluginAccept,
    loaded: loaded.map((l) => l.url),
    vertices: loaded.reduce((a, l) => a + l.vertices, 0),
    levels,
    failed,
    stats: { ...tiles.stats },
    errors: errors.slice(),
  };
};

function countVertices(obj) {
  let n = 0;
  obj.traverse((o) => {
    if (o.geometry && o.geometry.attributes && o.geometry.attributes.position) n += o.geometry.attributes.position.count;
  });
  return n;
}

window.qmThreeReady = true;
