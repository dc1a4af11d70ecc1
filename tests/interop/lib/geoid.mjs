// The EGM96 geoid from a GTX grid (Debian's proj-data: /usr/share/proj/egm96_15.gtx), read here
// with no terrastream code: 4 big-endian f64 (latitude and longitude of the south-west node,
// Δlatitude, Δlongitude, degrees), 2 big-endian i32 (rows, columns), then rows × columns
// big-endian f32 undulations in metres, south row first. Bilinear between the four nodes
// around a point; longitudes wrap when the grid spans the whole circle.
import fs from 'node:fs';

export const EGM96_GTX = '/usr/share/proj/egm96_15.gtx';

/** Reads a GTX file: `{ lat0, lon0, dlat, dlon, rows, cols, undulation(lonDeg, latDeg) }`. */
export function readGtx(file = EGM96_GTX) {
  let buf;
  try {
    buf = fs.readFileSync(file);
  } catch (err) {
    throw new Error(`${file}: ${err.code === 'ENOENT' ? 'missing (apt-get install -y proj-data)' : err.message}`);
  }
  if (buf.length < 40) throw new Error(`${file}: ${buf.length} bytes, too short for a GTX header`);
  const lat0 = buf.readDoubleBE(0), lon0 = buf.readDoubleBE(8), dlat = buf.readDoubleBE(16), dlon = buf.readDoubleBE(24);
  const rows = buf.readInt32BE(32), cols = buf.readInt32BE(36);
  if (!(rows > 1 && cols > 1 && dlat > 0 && dlon > 0)) throw new Error(`${file}: not a GTX grid (rows ${rows}, columns ${cols}, steps ${dlat}, ${dlon})`);
  if (buf.length !== 40 + 4 * rows * cols) throw new Error(`${file}: ${buf.length} bytes, a ${rows}×${cols} GTX grid has ${40 + 4 * rows * cols}`);
  // the whole circle: the column after the last is the first again
  const wraps = Math.abs(cols * dlon - 360) < 1e-9;
  const node = (r, c) => buf.readFloatBE(40 + 4 * (r * cols + c));
  return {
    lat0, lon0, dlat, dlon, rows, cols,
    /** The undulation (metres) at a longitude and latitude in degrees; throws outside the grid. */
    undulation(lonDeg, latDeg) {
      const y = (latDeg - lat0) / dlat;
      let x = (lonDeg - lon0) / dlon;
      if (wraps) x = ((x % cols) + cols) % cols;
      if (!(y >= 0 && y <= rows - 1) || !(x >= 0 && (wraps || x <= cols - 1))) {
        throw new Error(`${file}: lon ${lonDeg}, lat ${latDeg} is outside the grid`);
      }
      const r = Math.min(Math.floor(y), rows - 2), c = Math.floor(x);
      const c1 = wraps ? (c + 1) % cols : Math.min(c + 1, cols - 1);
      const fy = y - r, fx = x - c;
      const south = node(r, c) * (1 - fx) + node(r, c1) * fx;
      const north = node(r + 1, c) * (1 - fx) + node(r + 1, c1) * fx;
      return south * (1 - fy) + north * fy;
    },
  };
}
