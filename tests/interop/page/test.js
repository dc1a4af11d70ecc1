/* global Cesium */
// The CesiumJS side of the interop checks. run.mjs drives it through puppeteer:
//   await interopLoad(tilesetUrl, timeoutMs)  -> what was loaded / failed
//   await interopHeights([[e, n, u], …], timeoutMs) -> expected vs sampled heights
//   await interopHeightsAt([[lonDeg, latDeg], …], timeoutMs) -> sampled heights there
// No Cesium ion: no imagery, ellipsoid terrain, no geocoder; every request stays on 127.0.0.1.
'use strict';

window.interop = { errors: [] };
window.addEventListener('error', (e) => window.interop.errors.push(String(e.message)));
window.addEventListener('unhandledrejection', (e) => window.interop.errors.push(String(e.reason && (e.reason.stack || e.reason))));

function createViewer() {
  const viewer = new Cesium.Viewer('cesiumContainer', {
    baseLayer: false,
    baseLayerPicker: false,
    geocoder: false,
    terrainProvider: new Cesium.EllipsoidTerrainProvider(),
    animation: false,
    timeline: false,
    homeButton: false,
    sceneModePicker: false,
    navigationHelpButton: false,
    infoBox: false,
    selectionIndicator: false,
    fullscreenButton: false,
    vrButton: false,
    projectionPicker: false,
    msaaSamples: 1,
    contextOptions: { webgl: { preserveDrawingBuffer: true } },
  });
  viewer.scene.globe.baseColor = Cesium.Color.fromCssColorString('#2a3440');
  viewer.scene.debugShowFramesPerSecond = false;
  return viewer;
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

function withTimeout(promise, ms, what) {
  let timer;
  return Promise.race([
    promise.finally(() => clearTimeout(timer)),
    new Promise((_, reject) => {
      timer = setTimeout(() => reject(new Error(`${what} did not finish within ${ms / 1000} s`)), ms);
    }),
  ]);
}

window.interopLoad = async function interopLoad(url, timeoutMs) {
  const started = performance.now();
  const viewer = (window.viewer = window.viewer || createViewer());
  const loaded = (window.interop.loaded = []);
  const failed = (window.interop.failed = []);
  const tileset = await withTimeout(Cesium.Cesium3DTileset.fromUrl(url, { maximumScreenSpaceError: 4 }), timeoutMs, 'Cesium3DTileset.fromUrl');
  window.tileset = tileset;
  tileset.tileFailed.addEventListener((e) => failed.push({ url: String(e.url), message: String(e.message) }));
  tileset.tileLoad.addEventListener((tile) => {
    const c = tile.content;
    loaded.push(String((c && c.url) || (tile._contentResource && tile._contentResource.url) || '?'));
  });
  viewer.scene.primitives.add(tileset);
  const view = new Cesium.HeadingPitchRange(0, Cesium.Math.toRadians(-35), tileset.boundingSphere.radius * 2.5);
  await withTimeout(viewer.zoomTo(tileset, view), timeoutMs, 'viewer.zoomTo');
  let settled = false;
  let stableSince = null;
  while (performance.now() - started < timeoutMs) {
    await sleep(200);
    if (failed.length) {
      // give the other requests a moment, but a failure is final
      await sleep(1000);
      break;
    }
    if (tileset.tilesLoaded && loaded.length > 0) {
      stableSince = stableSince || performance.now();
      if (performance.now() - stableSince > 600) {
        settled = true;
        break;
      }
    } else {
      stableSince = null;
    }
  }
  const bs = tileset.boundingSphere;
  const centre = Cesium.Cartographic.fromCartesian(bs.center);
  return {
    settled,
    tilesLoaded: tileset.tilesLoaded,
    loaded,
    failed,
    ms: Math.round(performance.now() - started),
    rootTransform: Cesium.Matrix4.toArray(tileset.root.transform),
    boundingSphere: {
      radius: bs.radius,
      lon: centre ? Cesium.Math.toDegrees(centre.longitude) : null,
      lat: centre ? Cesium.Math.toDegrees(centre.latitude) : null,
      height: centre ? centre.height : null,
    },
    sampleHeightSupported: viewer.scene.sampleHeightSupported,
    pageErrors: window.interop.errors.slice(),
  };
};

/**
 * points: local east-north-up coordinates [[e, n, u], …] of the root tile's frame. Each goes
 * through the root transform to ECEF and a Cartographic (lon, lat, expected height); the rendered
 * height there comes from scene.sampleHeightMostDetailed (the globe hidden, only the tileset).
 */
window.interopHeights = async function interopHeights(points, timeoutMs) {
  const viewer = window.viewer;
  const tileset = window.tileset;
  if (!viewer || !tileset) throw new Error('no tileset loaded');
  if (!viewer.scene.sampleHeightSupported) throw new Error('scene.sampleHeightSupported is false (no depth textures)');
  const T = tileset.root.transform;
  const expected = points.map(([e, n, u]) => {
    const ecef = Cesium.Matrix4.multiplyByPoint(T, new Cesium.Cartesian3(e, n, u), new Cesium.Cartesian3());
    const c = Cesium.Cartographic.fromCartesian(ecef);
    return { lon: c.longitude, lat: c.latitude, h: c.height, ecef: [ecef.x, ecef.y, ecef.z] };
  });
  const { ms, heights } = await sampleHeights(viewer, expected.map((x) => new Cesium.Cartographic(x.lon, x.lat, 0)), timeoutMs);
  return {
    ms,
    loaded: window.interop.loaded.slice(),
    failed: window.interop.failed.slice(),
    samples: expected.map((x, i) => ({
      lonDeg: Cesium.Math.toDegrees(x.lon),
      latDeg: Cesium.Math.toDegrees(x.lat),
      expected: x.h,
      sampled: heights[i],
      ecef: x.ecef,
    })),
  };
};

/** scene.sampleHeightMostDetailed at Cartographics, the globe hidden (only the tileset counts). */
async function sampleHeights(viewer, query, timeoutMs) {
  viewer.scene.globe.show = false;
  const started = performance.now();
  try {
    const result = await withTimeout(viewer.scene.sampleHeightMostDetailed(query), timeoutMs, 'scene.sampleHeightMostDetailed');
    return {
      ms: Math.round(performance.now() - started),
      heights: result.map((c) => (c && typeof c.height === 'number' ? c.height : null)),
    };
  } finally {
    viewer.scene.globe.show = true;
  }
}

/**
 * points: [[lonDeg, latDeg], …] (WGS 84). The height CesiumJS finds on the tileset there, by
 * scene.sampleHeightMostDetailed; the caller knows what to expect (computed without Cesium).
 */
window.interopHeightsAt = async function interopHeightsAt(points, timeoutMs) {
  const viewer = window.viewer;
  if (!viewer || !window.tileset) throw new Error('no tileset loaded');
  if (!viewer.scene.sampleHeightSupported) throw new Error('scene.sampleHeightSupported is false (no depth textures)');
  const query = points.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat, 0));
  const { ms, heights } = await sampleHeights(viewer, query, timeoutMs);
  return { ms, loaded: window.interop.loaded.slice(), failed: window.interop.failed.slice(), heights };
};

window.interop.ready = true;
