// A small GeoTIFF reader for the viewer and height checks: one band of a stripped TIFF, stored,
// deflate- or LZW-compressed, 8/16/32-bit integers or 32/64-bit floats, its georeference
// (ModelTiepoint + ModelPixelScale, PixelIsArea or PixelIsPoint) and the EPSG codes of its
// GeoKeys. Independent of terrastream's own reader; anything else is refused by name.
import fs from 'node:fs';
import zlib from 'node:zlib';

const TYPE_SIZE = { 1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 16: 8 };

/**
 * TIFF's LZW (TIFF 6.0 section 13): codes of 9 to 12 bits, most significant bit first, 256
 * clears the table, 257 ends the strip, and the code width grows one code early (when the next
 * free code is 511, 1023, 2047). Returns the decoded bytes; a malformed stream throws.
 */
export function lzwDecode(input) {
  const prefix = new Int32Array(4096), last = new Uint8Array(4096), first = new Uint8Array(4096), length = new Int32Array(4096);
  for (let i = 0; i < 256; i++) {
    prefix[i] = -1;
    last[i] = i;
    first[i] = i;
    length[i] = 1;
  }
  let out = new Uint8Array(Math.max(1024, input.length * 3)), n = 0;
  const emit = (code) => {
    const len = length[code];
    if (n + len > out.length) {
      const bigger = new Uint8Array(Math.max(out.length * 2, n + len));
      bigger.set(out.subarray(0, n));
      out = bigger;
    }
    for (let c = code, k = n + len - 1; k >= n; k--, c = prefix[c]) out[k] = last[c];
    n += len;
  };
  let bit = 0, width = 9, next = 258, old = -1;
  const totalBits = input.length * 8;
  const read = () => {
    if (bit + width > totalBits) return 257;   // a strip may end without its end code
    let v = 0;
    for (let k = 0; k < width; k++, bit++) v = (v << 1) | ((input[bit >> 3] >> (7 - (bit & 7))) & 1);
    return v;
  };
  for (;;) {
    const code = read();
    if (code === 257) break;
    if (code === 256) {
      next = 258;
      width = 9;
      old = -1;
      continue;
    }
    if (old === -1) {
      if (code > 255) throw new Error(`LZW: code ${code} right after a clear`);
      emit(code);
      old = code;
      continue;
    }
    if (code > next) throw new Error(`LZW: code ${code} beyond the table (next ${next})`);
    if (next >= 4096) throw new Error('LZW: the table is full and no clear code came');
    // the new entry: old's string plus the first byte of code's string (or of old's, for the
    // code being defined right now)
    prefix[next] = old;
    last[next] = code < next ? first[code] : first[old];
    first[next] = first[old];
    length[next] = length[old] + 1;
    next++;
    emit(code);
    old = code;
    if (next + 1 >= 1 << width && width < 12) width++;
  }
  return out.subarray(0, n);
}

// GeoKeys read: GTRasterTypeGeoKey (1025; 2 is PixelIsPoint), GeographicTypeGeoKey (2048),
// ProjectedCSTypeGeoKey (3072), VerticalCSTypeGeoKey (4096).
const RASTER_TYPE = 1025, GEOGRAPHIC = 2048, PROJECTED = 3072, VERTICAL = 4096;

/**
 * Reads `file`: `{ width, height, nodata, pixelIsPoint, epsg, verticalEpsg, at(col, row),
 * world(col, row) }`, where `world` is the map position (x, y) of the sample's centre in the
 * file's CRS, `epsg` the CRS's code (the projected one, else the geographic one; null when the
 * keys give none) and `at` NaN for no-data.
 */
export function readGeoTiff(file) {
  const buf = fs.readFileSync(file);
  const fail = (msg) => {
    throw new Error(`${file}: ${msg}`);
  };
  const order = buf.toString('latin1', 0, 2);
  if (order !== 'II' && order !== 'MM') fail('not a TIFF (no II/MM byte order mark)');
  const le = order === 'II';
  const u16 = (o) => (le ? buf.readUInt16LE(o) : buf.readUInt16BE(o));
  const u32 = (o) => (le ? buf.readUInt32LE(o) : buf.readUInt32BE(o));
  const f64 = (o) => (le ? buf.readDoubleLE(o) : buf.readDoubleBE(o));
  if (u16(2) !== 42) fail(u16(2) === 43 ? 'BigTIFF is not read by this test reader' : 'not a classic TIFF (magic is not 42)');
  const ifd = u32(4);
  const tags = new Map();
  for (let i = 0, n = u16(ifd); i < n; i++) {
    const e = ifd + 2 + i * 12;
    const tag = u16(e), type = u16(e + 2), count = u32(e + 4);
    const size = TYPE_SIZE[type];
    if (!size) continue;
    const at = size * count <= 4 ? e + 8 : u32(e + 8);
    if (at + size * count > buf.length) fail(`tag ${tag} runs past the end of the file`);
    const read = (k) => {
      const o = at + k * size;
      switch (type) {
        case 3: return u16(o);
        case 4: return u32(o);
        case 8: return le ? buf.readInt16LE(o) : buf.readInt16BE(o);
        case 9: return le ? buf.readInt32LE(o) : buf.readInt32BE(o);
        case 11: return le ? buf.readFloatLE(o) : buf.readFloatBE(o);
        case 12: return f64(o);
        case 2: return buf[o];
        default: return buf[o];
      }
    };
    const values = [];
    for (let k = 0; k < count; k++) values.push(read(k));
    tags.set(tag, type === 2 ? String.fromCharCode(...values).replace(/\0+$/, '') : values);
  }
  const one = (tag, dflt) => (tags.has(tag) ? tags.get(tag)[0] : dflt);
  const width = one(256), height = one(257);
  if (!(width > 0 && height > 0)) fail('no image size');
  if (one(277, 1) !== 1) fail(`${one(277)} samples per pixel; one band expected`);
  if (tags.has(322)) fail('tiled TIFF; this test reader reads strips only');
  const compression = one(259, 1);
  if (![1, 5, 8, 32946].includes(compression)) fail(`compression ${compression}; stored, LZW or deflate expected`);
  if (one(317, 1) !== 1) fail(`predictor ${one(317)}; none expected`);
  const bits = one(258, 1), format = one(339, 1);
  const kinds = {
    '1/8': ['readUInt8', 'readUInt8'], '2/8': ['readInt8', 'readInt8'],
    '1/16': ['readUInt16LE', 'readUInt16BE'], '2/16': ['readInt16LE', 'readInt16BE'],
    '1/32': ['readUInt32LE', 'readUInt32BE'], '2/32': ['readInt32LE', 'readInt32BE'],
    '3/32': ['readFloatLE', 'readFloatBE'], '3/64': ['readDoubleLE', 'readDoubleBE'],
  };
  const kind = kinds[`${format}/${bits}`];
  if (!kind) fail(`sample format ${format} with ${bits} bits is not read by this test reader`);
  const bytes = bits / 8, readSample = kind[le ? 0 : 1];
  const rowsPerStrip = Math.min(one(278, height), height);
  const offsets = tags.get(273), counts = tags.get(279);
  if (!offsets || !counts || offsets.length !== counts.length) fail('strip offsets and byte counts missing or of different lengths');
  const values = new Float64Array(width * height);
  let row = 0;
  for (let s = 0; s < offsets.length && row < height; s++) {
    if (offsets[s] + counts[s] > buf.length) fail(`strip ${s} runs past the end of the file`);
    let strip = buf.subarray(offsets[s], offsets[s] + counts[s]);
    if (compression === 5) strip = Buffer.from(lzwDecode(strip));
    else if (compression !== 1) strip = zlib.inflateSync(strip);
    const rows = Math.min(rowsPerStrip, height - row);
    if (strip.length < rows * width * bytes) fail(`strip ${s} holds ${strip.length} bytes, ${rows * width * bytes} expected`);
    for (let i = 0; i < rows * width; i++) values[row * width + i] = strip[readSample](i * bytes);
    row += rows;
  }
  if (row < height) fail(`the strips hold ${row} of ${height} rows`);
  const scale = tags.get(33550), tie = tags.get(33922);
  if (!scale || !tie || tie.length < 6) fail('no ModelPixelScale/ModelTiepoint georeference');
  if (tags.has(34264)) fail('a ModelTransformation georeference is not read by this test reader');
  // GeoKeyDirectory: GTRasterTypeGeoKey (1025) = 2 is PixelIsPoint, where the tie point is the
  // centre of its pixel; otherwise (PixelIsArea) it is the pixel's corner.
  // Only keys stored in the directory itself (location 0) are read: the ones above all are.
  const keys = tags.get(34735) ?? [];
  const geoKey = (id) => {
    for (let k = 4; k + 3 < keys.length; k += 4) if (keys[k] === id && keys[k + 1] === 0) return keys[k + 3];
    return null;
  };
  const pixelIsPoint = geoKey(RASTER_TYPE) === 2;
  const half = pixelIsPoint ? 0 : 0.5;
  const userDefined = (v) => (v === null || v === 32767 ? null : v);
  const epsg = userDefined(geoKey(PROJECTED)) ?? userDefined(geoKey(GEOGRAPHIC));
  const nodataText = tags.get(42113);
  let nodata = typeof nodataText === 'string' && nodataText.trim() !== '' ? Number(nodataText) : null;
  // GDAL writes the no-data value in decimal ("-3.4e+38"); a float32 sample holds it rounded.
  if (nodata !== null && format === 3 && bits === 32) nodata = Math.fround(nodata);
  return {
    width,
    height,
    nodata,
    pixelIsPoint,
    epsg,
    verticalEpsg: userDefined(geoKey(VERTICAL)),
    at: (col, row) => {
      const v = values[row * width + col];
      return nodata !== null && v === nodata ? NaN : v;
    },
    world: (col, row) => [tie[3] + (col - tie[0] + half) * scale[0], tie[4] - (row - tie[1] + half) * scale[1]],
  };
}
