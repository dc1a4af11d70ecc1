// Child processes (the terrastream binary), free ports, and waiting for readiness.
import { spawn } from 'node:child_process';
import net from 'node:net';

const children = new Set();

/** Kills every child still running (used on exit and on the hard timeout). */
export function killAllChildren(signal = 'SIGKILL') {
  for (const child of children) {
    try {
      child.kill(signal);
    } catch {
      // already gone
    }
  }
}

/**
 * Runs `bin args…` to completion (killed after `timeoutMs`); resolves to
 * `{code, signal, stdout, stderr, ms, timedOut}`; never rejects unless the spawn itself fails.
 */
export function runCommand(bin, args, { timeoutMs = 240_000, env = process.env } = {}) {
  return new Promise((resolve, reject) => {
    const started = Date.now();
    const child = spawn(bin, args, { env, stdio: ['ignore', 'pipe', 'pipe'] });
    children.add(child);
    let stdout = '';
    let stderr = '';
    let timedOut = false;
    child.stdout.on('data', (d) => (stdout += d));
    child.stderr.on('data', (d) => (stderr += d));
    const timer = setTimeout(() => {
      timedOut = true;
      child.kill('SIGKILL');
    }, timeoutMs);
    child.on('error', (err) => {
      clearTimeout(timer);
      children.delete(child);
      reject(err);
    });
    child.on('close', (code, signal) => {
      clearTimeout(timer);
      children.delete(child);
      resolve({ code, signal, stdout, stderr, ms: Date.now() - started, timedOut });
    });
  });
}

/** Starts a long-running child; its output is kept (last 64 KiB) for failure messages. */
export function startDaemon(bin, args, { env = process.env } = {}) {
  const child = spawn(bin, args, { env, stdio: ['ignore', 'pipe', 'pipe'] });
  children.add(child);
  const state = { child, output: '', exited: null };
  const keep = (d) => {
    state.output = (state.output + d).slice(-65536);
  };
  child.stdout.on('data', keep);
  child.stderr.on('data', keep);
  child.on('error', (err) => {
    state.exited = { error: err.message };
    children.delete(child);
  });
  child.on('exit', (code, signal) => {
    state.exited = { code, signal };
    children.delete(child);
  });
  return state;
}

/** SIGTERM, then SIGKILL after `graceMs`; resolves once the child has exited. */
export async function stopDaemon(state, graceMs = 5000) {
  const { child } = state;
  if (!state.exited && child.exitCode === null && child.signalCode === null) {
    await new Promise((resolve) => {
      const timer = setTimeout(() => child.kill('SIGKILL'), graceMs);
      child.once('exit', () => {
        clearTimeout(timer);
        resolve();
      });
      child.kill('SIGTERM');
    });
  }
  // let go of our ends of its pipes (a grandchild may still hold theirs)
  child.stdout?.destroy();
  child.stderr?.destroy();
}

/** A TCP port that is free on 127.0.0.1 right now. */
export function freePort() {
  return new Promise((resolve, reject) => {
    const srv = net.createServer();
    srv.unref();
    srv.on('error', reject);
    srv.listen(0, '127.0.0.1', () => {
      const { port } = srv.address();
      srv.close(() => resolve(port));
    });
  });
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Fetch with a time limit. */
export async function fetchWithTimeout(url, { timeoutMs = 30_000, ...init } = {}) {
  return fetch(url, { ...init, signal: AbortSignal.timeout(timeoutMs) });
}

/** Polls `url` until it answers 200; throws with the last status/error and the daemon's output. */
export async function waitReady(url, daemon, timeoutMs = 60_000) {
  const deadline = Date.now() + timeoutMs;
  let last = 'no answer';
  while (Date.now() < deadline) {
    if (daemon.exited) {
      throw new Error(`the server exited before it was ready (${JSON.stringify(daemon.exited)}); its output:\n${daemon.output}`);
    }
    try {
      const res = await fetchWithTimeout(url, { timeoutMs: 2000 });
      await res.arrayBuffer();
      if (res.status === 200) return;
      last = `status ${res.status}`;
    } catch (err) {
      last = err.cause?.code || err.message;
    }
    await sleep(200);
  }
  throw new Error(`GET ${url} did not answer 200 within ${timeoutMs / 1000} s (last: ${last}); server output:\n${daemon.output}`);
}
