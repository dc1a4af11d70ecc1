/* global Cesium */
// The CesiumJS side of the quantized-mesh terrain checks, added by run.mjs to
// docs/examples/cesium-terrain.html (served with its CesiumJS URL pointed at the local copy)
// once the page is ready. It uses what the page keeps in window.terrastream (viewer,
// terrainProvider, errors):
//   await terrainFlight(stops, msPerStop) -> per stop: settled, ms, tiles drawn and their levels;
//                                            tiles CesiumJS gave up on; mesh failures
//   await terrainSample([[lonDeg, latDeg], …], ms) -> sampleTerrainMostDetailed heights, levels
// Tile failures come from three places: the provider's errorEvent (HTTP errors and tiles that do
// not decode: the page records them), meshes that CesiumJS's worker could not make (recorded
// here, by wrapping QuantizedMeshTerrainData.createMesh), and quadtree tiles left FAILED.
'use strict';

(function () {
  const meshFailures = (window.terrainMeshFailures = []);
  const proto = Cesium.QuantizedMeshTerrainData.prototype;
  const createMesh = proto.createMesh;
  proto.createMesh = function (options) {
    const p = createMesh.call(this, options);
    if (p && typeof p.then === 'function') {
      p.catch((err) => meshFailures.push(`${options.level}/${options.x}/${options.y}: ${String((err && err.message) || err)}`));
    }
    return p;
  };

  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

  // Cesium's quadtree counts y from the north; quantized-mesh (TMS) from the south.
  const qmName = (t) => `${t.level}/${t.x}/${(1 << t.level) - 1 - t.y}`;

  /** The globe's quadtree: tiles drawn this frame (by level) and tiles that failed for good. */
  function quadtree(globe) {
    const surface = globe._surface;
    const drawn = surface._tilesToRender || [];
    const levels = {};
    for (const t of drawn) levels[t.level] = (levels[t.level] || 0) + 1;
    const failed = [];
    const stack = [...(surface._levelZeroTiles || [])];
    let total = 0;
    while (stack.length) {
      const t = stack.pop();
      total++;
      if (t.state === Cesium.QuadtreeTileLoadState.FAILED) failed.push(qmName(t));
      for (const c of [t._southwestChild, t._southeastChild, t._northwestChild, t._northeastChild]) if (c) stack.push(c);
    }
    return { drawn: drawn.length, levels, failed, total };
  }

  /**
   * Flies the camera through `stops` ({lon, lat, h, range, pitch, heading} in degrees and
   * metres: looking at (lon, lat, h) from `range` away), waiting at each until the globe has
   * loaded every tile it wants (tilesLoaded for 600 ms running) or `msPerStop` has passed.
   */
  window.terrainFlight = async function terrainFlight(stops, msPerStop) {
    const { viewer } = window.terrastream;
    const scene = viewer.scene;
    const out = [];
    for (const s of stops) {
      const started = performance.now();
      const target = Cesium.Cartesian3.fromDegrees(s.lon, s.lat, s.h || 0);
      viewer.camera.lookAt(target, new Cesium.HeadingPitchRange(Cesium.Math.toRadians(s.heading || 0), Cesium.Math.toRadians(s.pitch), s.range));
      viewer.camera.lookAtTransform(Cesium.Matrix4.IDENTITY);
      let settled = false;
      let since = null;
      let frames = 0;
      const onFrame = () => frames++;
      scene.postRender.addEventListener(onFrame);
      while (performance.now() - started < msPerStop) {
        await sleep(100);
        if (scene.globe.tilesLoaded && frames > 2) {
          since = since || performance.now();
          if (performance.now() - since > 600) {
            settled = true;
            break;
          }
        } else since = null;
      }
      scene.postRender.removeEventListener(onFrame);
      const q = quadtree(scene.globe);
      const camera = Cesium.Cartographic.fromCartesian(viewer.camera.positionWC);
      out.push({
        stop: s,
        settled,
        ms: Math.round(performance.now() - started),
        frames,
        cameraHeight: camera ? camera.height : null,
        drawn: q.drawn,
        levels: q.levels,
        failedTiles: q.failed,
      });
    }
    return {
      stops: out,
      providerErrors: window.terrastream.errors.slice(),
      meshFailures: meshFailures.slice(),
    };
  };

  /**
   * Cesium.sampleTerrainMostDetailed at [[lonDeg, latDeg], …] (rejecting when a tile fails):
   * the heights, and the level availability says is the most detailed at each point.
   */
  window.terrainSample = async function terrainSample(points, ms) {
    const provider = window.terrastream.terrainProvider;
    // NaN until sampled: a point CesiumJS finds no terrain for stays NaN (null in the result)
    const cartos = points.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat, NaN));
    const started = performance.now();
    let timer;
    const timeout = new Promise((_, reject) => {
      timer = setTimeout(() => reject(new Error(`sampleTerrainMostDetailed did not finish within ${ms / 1000} s`)), ms);
    });
    const done = await Promise.race([Cesium.sampleTerrainMostDetailed(provider, cartos, true), timeout]).finally(() => clearTimeout(timer));
    return {
      ms: Math.round(performance.now() - started),
      heights: done.map((c) => (c && Number.isFinite(c.height) ? c.height : null)),
      levels: cartos.map((c) => provider.availability.computeMaximumLevelAtPosition(c)),
      providerErrors: window.terrastream.errors.slice(),
    };
  };

  window.terrainFlightReady = true;
})();
