#!/usr/bin/env node
// Validate glTF 2.0 assets (.gltf or .glb) with the Khronos glTF-Validator's JS build.
//
// Usage: node validate.mjs FILE...
//
// Prints one JSON object per line, in the order given:
//   {"file": FILE, "errors": n, "warnings": n, "infos": n, "hints": n,
//    "truncated": bool, "messages": [{code, severity, pointer, message}, ...]}
// "messages" holds the first 20 errors (severity 0). When a file cannot be read or the
// validator itself throws, "errors" is 1 and "fatal" holds the reason.
// The exit code is 0 whatever was found (the caller decides); 2 only for a usage error.
//
// External resources (buffers, images) are read relative to the asset's own directory;
// a URI that is absolute, has a scheme, or escapes that directory is refused, which the
// validator then reports as an error (IO_ERROR). data: URIs are decoded by the validator
// itself and never reach the loader.
import fs from 'node:fs/promises';
import path from 'node:path';
import process from 'node:process';
import validator from 'gltf-validator';

const MAX_MESSAGES = 20;
// Cap on issues collected per file, so that a badly broken file (one error per index)
// cannot exhaust memory; "truncated" says when the cap was hit.
const MAX_ISSUES = 5000;

function makeLoader(assetPath) {
  const baseDir = path.dirname(path.resolve(assetPath));
  return async (uri) => {
    let decoded;
    try {
      decoded = decodeURIComponent(uri);
    } catch (e) {
      throw new Error(`malformed URI ${JSON.stringify(uri)}`);
    }
    if (/^[a-zA-Z][a-zA-Z0-9+.-]*:/.test(decoded) || path.isAbsolute(decoded) || decoded.includes('\0')) {
      throw new Error(`refusing non-relative URI ${JSON.stringify(uri)}`);
    }
    const resolved = path.resolve(baseDir, decoded);
    const rel = path.relative(baseDir, resolved);
    if (rel === '' || rel === '..' || rel.startsWith('..' + path.sep) || path.isAbsolute(rel)) {
      throw new Error(`refusing URI outside the asset's directory ${JSON.stringify(uri)}`);
    }
    // Refuse symlinks that lead out of the directory too.
    const real = await fs.realpath(resolved);
    const realBase = await fs.realpath(baseDir);
    const realRel = path.relative(realBase, real);
    if (realRel.startsWith('..' + path.sep) || realRel === '..' || path.isAbsolute(realRel)) {
      throw new Error(`refusing URI resolving outside the asset's directory ${JSON.stringify(uri)}`);
    }
    return new Uint8Array(await fs.readFile(real));
  };
}

async function validateFile(file) {
  const out = { file, errors: 0, warnings: 0, infos: 0, hints: 0, truncated: false, messages: [] };
  try {
    const bytes = new Uint8Array(await fs.readFile(file));
    const ext = path.extname(file).toLowerCase();
    const options = {
      uri: path.basename(file),
      maxIssues: MAX_ISSUES,
      writeTimestamp: false,
      externalResourceFunction: makeLoader(file),
    };
    if (ext === '.glb') options.format = 'glb';
    else if (ext === '.gltf') options.format = 'gltf';
    const report = await validator.validateBytes(bytes, options);
    const issues = report.issues;
    out.errors = issues.numErrors;
    out.warnings = issues.numWarnings;
    out.infos = issues.numInfos;
    out.hints = issues.numHints;
    out.truncated = Boolean(issues.truncated);
    out.messages = issues.messages
      .filter((m) => m.severity === 0)
      .slice(0, MAX_MESSAGES)
      .map((m) => ({ code: m.code, severity: m.severity, pointer: m.pointer ?? null, offset: m.offset ?? null, message: m.message }));
    // A short, severity-agnostic summary of what was found is handy in failure output.
    const codes = {};
    for (const m of issues.messages) codes[m.code] = (codes[m.code] || 0) + 1;
    out.codes = codes;
  } catch (e) {
    out.errors = 1;
    out.fatal = String(e && e.message ? e.message : e);
    out.messages = [{ code: 'FATAL', severity: 0, pointer: null, offset: null, message: out.fatal }];
  }
  return out;
}

async function main() {
  const files = process.argv.slice(2);
  if (files.length === 0) {
    process.stderr.write('usage: node validate.mjs FILE...\n');
    process.exitCode = 2;
    return;
  }
  // Sequential on purpose: each asset may be large; memory stays bounded by one file.
  for (const file of files) {
    const result = await validateFile(file);
    process.stdout.write(JSON.stringify(result) + '\n');
  }
}

await main();
