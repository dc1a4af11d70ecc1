// Named checks: each passes or fails with a message; all of them run, the summary line is last.

export class CheckFailure extends Error {
  constructor(message, details = []) {
    super(message);
    this.details = details;
  }
}

export class Checks {
  constructor() {
    this.results = [];
  }

  /**
   * Runs `fn(log)`; `log(line)` prints a detail line under the check. `fn` returns the pass
   * message, or throws (a `CheckFailure` carries detail lines) to fail.
   */
  async run(name, fn) {
    const started = Date.now();
    const details = [];
    const log = (line) => details.push(String(line));
    console.log(`--- ${name}`);
    let ok = false;
    let message;
    try {
      message = (await fn(log)) ?? 'ok';
      ok = true;
    } catch (err) {
      message = err instanceof CheckFailure ? err.message : (err && err.stack) || String(err);
      if (err instanceof CheckFailure) details.push(...err.details);
    }
    this.#record(name, ok, message, details, Date.now() - started);
    return ok;
  }

  /** Records a failed check that could not run. */
  fail(name, message, details = []) {
    console.log(`--- ${name}`);
    this.#record(name, false, message, details, 0);
  }

  #record(name, ok, message, details, ms) {
    for (const line of details) console.log(`    ${line}`);
    console.log(`${ok ? 'PASS' : 'FAIL'} ${name} (${(ms / 1000).toFixed(1)} s): ${message}`);
    this.results.push({ name, ok, message });
  }

  get failed() {
    return this.results.filter((r) => !r.ok).length;
  }

  get passed() {
    return this.results.filter((r) => r.ok).length;
  }

  summary() {
    const lines = ['', '=== summary'];
    for (const r of this.results) lines.push(`${r.ok ? 'PASS' : 'FAIL'} ${r.name}: ${firstLine(r.message)}`);
    return lines.join('\n');
  }
}

function firstLine(s) {
  const line = String(s).split('\n')[0];
  return line.length > 200 ? `${line.slice(0, 197)}...` : line;
}
