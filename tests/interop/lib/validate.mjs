// Check b: every GLB through the Khronos glTF validator.
import validator from 'gltf-validator';
import { CheckFailure } from './checks.mjs';

const SEVERITY = ['error', 'warning', 'info', 'hint'];

export async function validateGlbs(glbs, log) {
  if (glbs.length === 0) throw new CheckFailure('no GLB to validate (the walk collected none)');
  let errors = 0;
  let warnings = 0;
  let infos = 0;
  const failing = [];
  const warningCodes = new Map();
  for (const { url, buf } of glbs) {
    let report;
    try {
      report = await validator.validateBytes(new Uint8Array(buf), {
        uri: new URL(url).pathname.split('/').pop(),
        maxIssues: 100,
        // a GLB tile must be self-contained: any external resource is an error
        externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} in a GLB tile`)),
      });
    } catch (err) {
      errors++;
      failing.push(`${url}: the validator threw: ${err?.message ?? err}`);
      continue;
    }
    const { numErrors, numWarnings, numInfos, messages } = report.issues;
    errors += numErrors;
    warnings += numWarnings;
    infos += numInfos;
    for (const m of messages) {
      if (m.severity === 1) warningCodes.set(m.code, (warningCodes.get(m.code) ?? 0) + 1);
    }
    if (numErrors > 0) {
      failing.push(`${url}: ${numErrors} errors, ${numWarnings} warnings`);
      for (const m of messages) {
        failing.push(`    [${SEVERITY[m.severity] ?? m.severity}] ${m.code} at ${m.pointer ?? '-'}: ${m.message}`);
      }
      if (report.issues.truncated) failing.push('    (issues truncated at 100)');
    }
  }
  const validatorVersion = validator.version();
  log(`gltf-validator ${validatorVersion}: ${glbs.length} GLBs, ${errors} errors, ${warnings} warnings, ${infos} infos`);
  for (const [code, n] of warningCodes) log(`warning ${code}: ${n}×`);
  if (failing.length) throw new CheckFailure(`${failing.filter((l) => !l.startsWith(' ')).length} of ${glbs.length} GLBs have validation errors (${errors} errors, ${warnings} warnings)`, failing);
  return `${glbs.length} GLBs valid: 0 errors, ${warnings} warnings, ${infos} infos`;
}
