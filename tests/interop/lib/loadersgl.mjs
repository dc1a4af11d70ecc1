// Check c: loaders.gl parses every tileset JSON (Tiles3DLoader) and every GLB (as 3D Tiles glTF content).
import { load, parse } from '@loaders.gl/core';
import { Tiles3DLoader } from '@loaders.gl/3d-tiles';
import { CheckFailure } from './checks.mjs';

function countTiles(root) {
  let tiles = 0;
  const contentUrls = [];
  const stack = root ? [root] : [];
  while (stack.length) {
    const t = stack.pop();
    tiles++;
    if (t.contentUrl) contentUrls.push(t.contentUrl);
    for (const c of t.children ?? []) stack.push(c);
  }
  return { tiles, contentUrls };
}

/** The message and the first frames of the stack. */
function short(err) {
  return String(err?.stack ?? err).split('\n').slice(0, 4).join('\n      ');
}

function sameUrl(a, b) {
  try {
    return decodeURI(new URL(a).href) === decodeURI(new URL(b).href);
  } catch {
    return a === b;
  }
}

export async function loadersGlCheck(walk, log) {
  const failures = [];
  let tilesetTiles = 0;
  for (const { url } of walk.jsons) {
    try {
      const ts = await load(url, Tiles3DLoader, { '3d-tiles': { loadGLTF: false, isTileset: true } });
      if (!ts.root) throw new Error('no root after parsing');
      const { tiles, contentUrls } = countTiles(ts.root);
      tilesetTiles += tiles;
      // loaders.gl resolves content URIs itself: they must name what new URL(uri, jsonUrl) names
      const expected = walk.tiles.filter((t) => t.tileset === url && t.contentUrl).map((t) => t.contentUrl);
      const missing = expected.filter((e) => !contentUrls.some((c) => sameUrl(c, e)));
      if (missing.length) failures.push(`${url}: loaders.gl resolved content URLs differently, e.g. expected ${missing[0]}, got ${contentUrls.slice(0, 3).join(', ')}`);
      log(`tileset ${url}: ${tiles} tiles, version ${ts.asset?.version}, type ${ts.type}`);
    } catch (err) {
      failures.push(`Tiles3DLoader on ${url} threw: ${short(err)}`);
    }
  }
  let nodes = 0;
  let vertices = 0;
  let primitives = 0;
  for (const { url, buf } of walk.glbs) {
    try {
      const ab = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
      const content = await parse(ab, Tiles3DLoader, { '3d-tiles': { loadGLTF: true, isTileset: false } });
      const gltf = content.gltf;
      if (!gltf) throw new Error(`no glTF parsed (content type ${content.type})`);
      nodes += gltf.nodes?.length ?? 0;
      let v = 0;
      for (const mesh of gltf.meshes ?? []) {
        for (const prim of mesh.primitives ?? []) {
          primitives++;
          const pos = prim.attributes?.POSITION;
          if (!pos) throw new Error('a primitive without POSITION');
          if (pos.value && pos.value.length < pos.count * 3) throw new Error(`POSITION decoded to ${pos.value.length} values for ${pos.count} vertices`);
          v += pos.count;
        }
      }
      vertices += v;
    } catch (err) {
      failures.push(`Tiles3DLoader on ${url} threw: ${short(err)}`);
    }
  }
  const msg = `${walk.jsons.length} tileset JSONs (${tilesetTiles} tiles), ${walk.glbs.length} GLBs: ${nodes} nodes, ${primitives} primitives, ${vertices} vertices`;
  if (walk.jsons.length === 0 || walk.glbs.length === 0) failures.unshift('nothing to parse (the walk collected no tileset or no GLB)');
  if (failures.length) throw new CheckFailure(`${failures.length} failures; ${msg}`, failures);
  return msg;
}
