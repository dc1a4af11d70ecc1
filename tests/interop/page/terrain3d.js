/* global Cesium */
// The page of check k. It draws the globe with Cesium3DTilesTerrainProvider on
// /tilesets/NAME/terrain/3dtiles/tileset.json and keeps, in window.terrastream, what
// terrain-flight.js (added by the check) flies with: viewer, terrainProvider, errors, ready.
// Also made: the quantized-mesh provider of the same terrain (qmProvider), not drawn, for
//   await terrain3dCompare([[lonDeg, latDeg], …], ms) -> sampleTerrainMostDetailed heights of
//                                                         both providers at the same points.
// A 3D Tiles terrain tile that CesiumJS cannot load is not an errorEvent: its provider logs
// "Could not load tile" and gives up on it; the check watches the console for that, and this
// page records meshes CesiumJS's worker could not make (Cesium3DTilesTerrainData.createMesh).
'use strict';

(function () {
  Cesium.Ion.defaultAccessToken = '';
  const params = new URLSearchParams(window.location.search);
  const server = (params.get('server') || window.location.origin).replace(/\/+$/, '');
  const name = params.get('tileset');
  const state = (window.terrastream = { server, tileset: name, viewer: null, terrainProvider: null, qmProvider: null, errors: [], meshFailures: [], ready: false, fatal: null });

  const proto = Cesium.Cesium3DTilesTerrainData.prototype;
  const createMesh = proto.createMesh;
  proto.createMesh = function (options) {
    const p = createMesh.call(this, options);
    if (p && typeof p.then === 'function') {
      p.catch((err) => state.meshFailures.push(`${options.level}/${options.x}/${options.y}: ${String((err && err.message) || err)}`));
    }
    return p;
  };

  async function main() {
    const base = `${server}/tilesets/${encodeURIComponent(name)}/terrain`;
    const terrainProvider = await Cesium.Cesium3DTilesTerrainProvider.fromUrl(`${base}/3dtiles/tileset.json`, { requestVertexNormals: true });
    terrainProvider.errorEvent.addEventListener((e) => state.errors.push(`3D Tiles: ${e.message}`));
    const qmProvider = await Cesium.CesiumTerrainProvider.fromUrl(`${base}/`, { requestVertexNormals: true });
    qmProvider.errorEvent.addEventListener((e) => state.errors.push(`quantized-mesh: ${e.message}`));
    // (?draw=quantized-mesh draws the other provider instead: the same view for comparison)
    const drawn = params.get('draw') === 'quantized-mesh' ? qmProvider : terrainProvider;
    const viewer = new Cesium.Viewer('cesiumContainer', {
      terrainProvider: drawn, baseLayer: false, baseLayerPicker: false, geocoder: false, animation: false, timeline: false,
      sceneModePicker: false, navigationHelpButton: false, fullscreenButton: false, infoBox: false, selectionIndicator: false,
    });
    // lit from the camera, as the docs example page does; no stars, sun or moon (they move with
    // the clock, so two page loads would differ where the sky shows)
    const scene = viewer.scene;
    scene.skyBox.show = false;
    scene.sun.show = false;
    scene.moon.show = false;
    scene.globe.enableLighting = true;
    scene.light = new Cesium.DirectionalLight({ direction: Cesium.Cartesian3.clone(scene.camera.directionWC) });
    scene.preRender.addEventListener(() => {
      scene.light.direction = Cesium.Cartesian3.clone(scene.camera.directionWC, scene.light.direction);
    });
    Object.assign(state, { viewer, terrainProvider, qmProvider, ready: true });
  }

  async function sample(provider, points) {
    const cartos = points.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat, NaN));
    const done = await Cesium.sampleTerrainMostDetailed(provider, cartos, true);
    return {
      heights: done.map((c) => (c && Number.isFinite(c.height) ? c.height : null)),
      levels: cartos.map((c) => provider.availability.computeMaximumLevelAtPosition(c)),
    };
  }

  window.terrain3dCompare = async function terrain3dCompare(points, ms) {
    const started = performance.now();
    let timer;
    const timeout = new Promise((_, reject) => {
      timer = setTimeout(() => reject(new Error(`sampleTerrainMostDetailed did not finish within ${ms / 1000} s`)), ms);
    });
    const both = Promise.all([sample(state.terrainProvider, points), sample(state.qmProvider, points)]);
    const [t3, qm] = await Promise.race([both, timeout]).finally(() => clearTimeout(timer));
    return { ms: Math.round(performance.now() - started), t3, qm, errors: state.errors.slice() };
  };

  main().catch((err) => {
    state.fatal = String((err && err.stack) || err);
  });
})();
