// MapLibre GL JS draws a terrastream tileset's heightmap tiles as 3D terrain with hillshade:
// ?tiles=<TileJSON URL>&lon=&lat=&zoom=&pitch=&hillshade=0|1. When the map is idle it reports
// errors, the heightmap tiles it loaded and the elevation it reads at the centre (window.__result).
import { Map } from '/maplibre-gl/maplibre-gl.mjs';

const q = new URLSearchParams(location.search);
const num = (k, d) => (q.has(k) ? Number(q.get(k)) : d);
const result = { errors: [], idle: false, elevation: null, tiles: 0 };
window.__result = result;
const hillshade = q.get('hillshade') !== '0';
const style = {
  version: 8,
  sources: {
    dem: { type: 'raster-dem', url: q.get('tiles'), tileSize: 256, encoding: q.get('encoding') || 'terrarium' },
  },
  layers: [
    { id: 'background', type: 'background', paint: { 'background-color': '#d8d8d8' } },
    ...(hillshade ? [{ id: 'hillshade', type: 'hillshade', source: 'dem', paint: { 'hillshade-exaggeration': 1 } }] : []),
  ],
  terrain: { source: 'dem', exaggeration: 1 },
};
const map = new Map({
  container: 'map',
  style,
  center: [num('lon', 0), num('lat', 0)],
  zoom: num('zoom', 10),
  pitch: num('pitch', 60),
  bearing: num('bearing', 20),
  fadeDuration: 0,
  attributionControl: false,
  canvasContextAttributes: { preserveDrawingBuffer: true },
});
map.on('error', (e) => result.errors.push(String(e?.error?.message ?? e?.error ?? e)));
map.on('sourcedata', (e) => {
  if (e.sourceId === 'dem' && e.tile) result.tiles += 1;
});
map.once('idle', () => {
  result.elevation = map.queryTerrainElevation([num('lon', 0), num('lat', 0)]);
  result.idle = true;
});
