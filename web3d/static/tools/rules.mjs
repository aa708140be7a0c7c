// The page's rules that its type check does not see (`npm run check` runs this after tsc): no module over 600
// lines and no function over 80, as tests/integration/test_code_size.py holds the Python packages to, and no HTML
// written into the document (innerHTML, outerHTML, insertAdjacentHTML, document.write): text and elements only.
// Usage: node tools/rules.mjs FILE...; prints each offence as FILE:LINE what, and exits 1 when there is one.

import { readFileSync } from "node:fs";
import ts from "typescript";

const MAX_MODULE_LINES = 600;
const MAX_FUNCTION_LINES = 80;
const HTML_SINKS = new Set(["innerHTML", "outerHTML", "insertAdjacentHTML"]);
const DOCUMENT_WRITES = new Set(["write", "writeln"]);

/**
 * A function's name as a reader finds it: its own, the variable or property it is assigned to, or "(anonymous)".
 * @param {ts.Node} node
 */
function nameOf(node) {
  const named = /** @type {{name?: ts.Node}} */ (node).name ?? /** @type {{name?: ts.Node}} */ (node.parent).name;
  return named && (ts.isIdentifier(named) || ts.isPrivateIdentifier(named)) ? named.text : "(anonymous)";
}

/**
 * The property a member access names (`a.b`, `a["b"]`), or null.
 * @param {ts.Node} node
 */
function member(node) {
  if (ts.isPropertyAccessExpression(node)) return { object: node.expression, name: node.name.text };
  if (ts.isElementAccessExpression(node) && ts.isStringLiteralLike(node.argumentExpression)) {
    return { object: node.expression, name: node.argumentExpression.text };
  }
  return null;
}

/**
 * The offences of one file.
 * @param {string} file
 */
function check(file) {
  const text = readFileSync(file, "utf8");
  const source = ts.createSourceFile(file, text, ts.ScriptTarget.Latest, true, ts.ScriptKind.JS);
  const line = (/** @type {number} */ pos) => source.getLineAndCharacterOfPosition(pos).line + 1;
  const found = [];
  const lines = text.split(/\r?\n/).length - (text.endsWith("\n") ? 1 : 0);
  if (lines > MAX_MODULE_LINES) found.push(`${file}:1 module: ${lines} lines, over ${MAX_MODULE_LINES}`);
  /** @param {ts.Node} node */
  const visit = (node) => {
    if (ts.isFunctionLike(node) && "body" in node && node.body) {
      const n = line(node.end) - line(node.getStart(source)) + 1;
      if (n > MAX_FUNCTION_LINES) {
        found.push(`${file}:${line(node.getStart(source))} ${nameOf(node)}: ${n} lines, over ${MAX_FUNCTION_LINES}`);
      }
    }
    const m = member(node);
    const isDocument = m && ts.isIdentifier(m.object) && m.object.text === "document";
    if (m && (HTML_SINKS.has(m.name) || (isDocument && DOCUMENT_WRITES.has(m.name)))) {
      found.push(`${file}:${line(node.getStart(source))} ${m.name} writes HTML: use textContent, createElement ` +
        "and replaceChildren");
    }
    ts.forEachChild(node, visit);
  };
  visit(source);
  return found;
}

const offences = process.argv.slice(2).flatMap(check);
for (const offence of offences) console.log(offence);
process.exit(offences.length ? 1 : 0);
