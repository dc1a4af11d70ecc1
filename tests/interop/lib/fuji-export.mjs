// The fuji tileset the GLB compression tests share: fuji.png baked with the binary under test
// (TERRASTREAM_BIN, default ../../target/release/terrastream; data from TERRASTREAM_DATA, default
// ../../../shared/data) and exported as 3D Tiles once per `--glb-compression` form asked for.
import path from 'node:path';
import { execFileSync } from 'node:child_process';
import { fileURLToPath } from 'node:url';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const DATA = process.env.TERRASTREAM_DATA ? path.resolve(process.env.TERRASTREAM_DATA) : path.resolve(HERE, '../../../../shared/data');
const BIN = process.env.TERRASTREAM_BIN ? path.resolve(process.env.TERRASTREAM_BIN) : path.resolve(HERE, '../../../target/release/terrastream');

// Bakes fuji into `tmp/fuji` (30 m cells, 1 m error, 4 point levels, 128-cell tiles) and exports
// it under `tmp/<form>` for each form ('none', 'meshopt', 'draco'); returns { form: dir }.
export function fujiExports(tmp, forms) {
  const ts = path.join(tmp, 'fuji');
  execFileSync(BIN, ['bake', '--quiet', path.join(DATA, 'fuji.png'), '--encoding', 'terrain-rgb', '--cell-size', '30',
    '--max-error', '1', '--levels', '4', '--tile-size', '128', '--out', ts]);
  const dirs = {};
  for (const form of forms) {
    dirs[form] = path.join(tmp, form);
    execFileSync(BIN, ['export', ts, '--format', '3dtiles', '--glb-compression', form, '--out', dirs[form], '--quiet']);
  }
  return dirs;
}
