// Where a raster sample lies on the Earth, computed with no terrastream code: the sample's map
// position from the GeoTIFF's own georeference, longitude and latitude by proj4js with the EPSG
// definition of the file's CRS, the ellipsoidal height as the raster value plus the EGM96
// undulation (lib/geoid.mjs) where the heights are EGM96, and WGS 84 Earth-centred coordinates.
import { createRequire } from 'node:module';

const require = createRequire(import.meta.url);
const proj4 = require('proj4');

// The CRSs of ../shared/data/geo/, as PROJ states their EPSG definitions
// (`projinfo EPSG:n -o PROJ`). A file in any other CRS is refused by name.
export const EPSG_DEFS = {
  4326: '+proj=longlat +datum=WGS84 +no_defs +type=crs',
  26918: '+proj=utm +zone=18 +datum=NAD83 +units=m +no_defs +type=crs',
  32632: '+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs +type=crs',
};

/** A function (x, y) → [lonDeg, latDeg] for EPSG:`epsg`; throws for a code not in EPSG_DEFS. */
export function toLonLat(epsg) {
  const def = EPSG_DEFS[epsg];
  if (!def) throw new Error(`EPSG:${epsg} is not among the definitions of lib/earth.mjs (${Object.keys(EPSG_DEFS).map((c) => `EPSG:${c}`).join(', ')})`);
  if (epsg === 4326) return (x, y) => [x, y];
  const p = proj4(def, EPSG_DEFS[4326]);
  return (x, y) => p.forward([x, y]);
}

const A = 6378137.0;
const F = 1 / 298.257223563;
const E2 = F * (2 - F);

/** WGS 84 longitude, latitude (degrees) and ellipsoidal height (m) → Earth-centred metres. */
export function ecefOf(lonDeg, latDeg, h) {
  const lam = (lonDeg * Math.PI) / 180, phi = (latDeg * Math.PI) / 180;
  const n = A / Math.sqrt(1 - E2 * Math.sin(phi) ** 2);
  return [(n + h) * Math.cos(phi) * Math.cos(lam), (n + h) * Math.cos(phi) * Math.sin(lam), (n * (1 - E2) + h) * Math.sin(phi)];
}

/**
 * A raster sample on the Earth: `{ col, row, x, y, lon, lat, value, undulation, h, ecef }`,
 * `h` ellipsoidal (`value` + `undulation`; the undulation is 0 without a geoid). NaN heights
 * for no-data.
 */
export function placeSample(raster, lonLatOf, geoid, col, row) {
  const [x, y] = raster.world(col, row);
  const [lon, lat] = lonLatOf(x, y);
  const value = raster.at(col, row);
  const undulation = geoid ? geoid.undulation(lon, lat) : 0;
  const h = value + undulation;
  return { col, row, x, y, lon, lat, value, undulation, h, ecef: ecefOf(lon, lat, h) };
}

/** True when the sample and its eight neighbours hold data (a hole's rim is no place to sample). */
export function validAround(raster, col, row) {
  for (let dr = -1; dr <= 1; dr++) for (let dc = -1; dc <= 1; dc++) {
    const c = col + dc, r = row + dr;
    if (c < 0 || r < 0 || c >= raster.width || r >= raster.height || !Number.isFinite(raster.at(c, r))) return false;
  }
  return true;
}

/**
 * A k×k grid of raster samples over columns `cols` = [first, last] and rows `rows` (default:
 * all but the outer 2 on every side). A grid point on or next to no-data moves to the nearest
 * sample (in cells) that is not; none within `reach` cells is an error.
 */
export function interiorGrid(raster, k, { cols = [2, raster.width - 3], rows = [2, raster.height - 3], reach = 8 } = {}) {
  const pick = ([a, b], i) => a + Math.round((i * (b - a)) / (k - 1));
  const out = [];
  for (let j = 0; j < k; j++) for (let i = 0; i < k; i++) {
    const col = pick(cols, i), row = pick(rows, j);
    let best = null;
    for (let d = 0; d <= reach && !best; d++) {
      for (let dr = -d; dr <= d && !best; dr++) for (let dc = -d; dc <= d && !best; dc++) {
        if (Math.max(Math.abs(dr), Math.abs(dc)) !== d) continue;
        if (validAround(raster, col + dc, row + dr)) best = { col: col + dc, row: row + dr, moved: d };
      }
    }
    if (!best) throw new Error(`no sample with data around (${col}, ${row}) within ${reach} cells`);
    out.push(best);
  }
  return out;
}
