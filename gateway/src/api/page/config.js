// The configuration as TOML: loaded, validated first, applied with If-Match of the version
// loaded.
import { $, el, plural } from './base.js';
import { api, refusal, canChange, loadConfigFacts } from './rest.js';

// --- configuration: TOML, validated first, applied with If-Match -----------------------

const C = { text: '', etag: '', validated: null };

/** The first and last text line of `[lines.<name>]` and its sub-tables in `text`. */
function lineBlock(text, name) {
  const rows = text.split('\n');
  const mine = new RegExp(`^\\s*\\[\\[?\\s*lines\\.${name.replace(/[.*+?^${}()|[\]\\]/g, '\\$&')}\\s*(\\]|\\.)`);
  const header = /^\s*\[/;
  let start = -1; let end = rows.length;
  for (let i = 0; i < rows.length; i += 1) {
    if (start < 0) { if (mine.test(rows[i])) start = i; continue; }
    if (header.test(rows[i]) && !mine.test(rows[i])) {
      end = i;
      while (end > start && /^\s*(#.*)?$/.test(rows[end - 1])) end -= 1;
      break;
    }
  }
  return start < 0 ? null : { rows, start, end };
}

function scopeText() {
  const name = $('cfg-scope').value;
  if (!name) return C.text;
  const b = lineBlock(C.text, name);
  return b ? b.rows.slice(b.start, b.end).join('\n') : `# lines.${name} is not in the file as written: add its table here\n[lines.${name}]\n`;
}

/** The whole file with the edited part put in its place. */
function fullText() {
  const name = $('cfg-scope').value;
  const edited = $('cfg-text').value;
  if (!name) return edited;
  const b = lineBlock(C.text, name);
  if (!b) return `${C.text.replace(/\n*$/, '\n\n')}${edited}\n`;
  return [...b.rows.slice(0, b.start), ...edited.split('\n'), ...b.rows.slice(b.end)].join('\n');
}

function cfgState(text, bad) {
  $('cfg-state').textContent = text;
  $('cfg-state').className = bad ? 'bad' : 'muted';
}

export async function cfgLoad() {
  const r = await api('GET', '/config', { headers: { Accept: 'application/toml' } });
  if (!r.ok) { cfgState(refusal(r), true); return; }
  C.text = r.text; C.etag = r.headers.get('ETag') || ''; C.validated = null;
  $('cfg-text').value = scopeText();
  $('cfg-issues').replaceChildren();
  $('cfg-apply').disabled = true;
  cfgState(`loaded, version ${C.etag}`);
}

function showIssues(issues) {
  $('cfg-issues').replaceChildren(...issues.map((i) => el('li', {},
    el('button', { type: 'button', onclick: () => jumpTo(i.path) }, i.path || '(the whole file)'), `: ${i.message}`)));
}

/** Selects the text line of `path`'s last key in the editor. */
function jumpTo(path) {
  const ta = $('cfg-text');
  const key = (path || '').split('.').pop().replace(/\[\d+\]$/, '');
  const rows = ta.value.split('\n');
  let at = 0;
  for (const row of rows) {
    if (key && new RegExp(`^\\s*${key.replace(/[.*+?^${}()|[\]\\]/g, '\\$&')}\\s*=`).test(row)) {
      ta.focus();
      ta.setSelectionRange(at, at + row.length);
      return;
    }
    at += row.length + 1;
  }
  ta.focus();
}

async function cfgValidate() {
  if (!C.text) await cfgLoad();
  const text = fullText();
  cfgState('validating…');
  $('cfg-apply').disabled = true;
  const r = await api('POST', '/config/validate', { body: text, headers: { 'Content-Type': 'application/toml' } });
  if (r.ok) {
    C.validated = text;
    $('cfg-issues').replaceChildren();
    cfgState(`valid: ${plural(r.json.lines, 'line')}, ${plural(r.json.devices, 'device')}; nothing changed yet: Apply puts it in force`);
    $('cfg-apply').disabled = !canChange();
  } else {
    C.validated = null;
    showIssues(r.issues);
    cfgState(r.issues.length ? `${plural(r.issues.length, 'problem')}, nothing changed: ${r.reason}` : `${refusal(r)}; nothing changed`, true);
  }
}

async function cfgApply() {
  const text = fullText();
  if (C.validated !== text) { cfgState('validate this text first', true); return; }
  cfgState('applying…');
  const r = await api('PUT', '/config', { body: text, headers: { 'Content-Type': 'application/toml', 'If-Match': C.etag } });
  $('cfg-apply').disabled = true;
  if (r.ok) {
    const a = (r.json && r.json.applied) || {};
    const did = Object.entries(a).filter(([, v]) => v.length).map(([k, v]) => `${k.replace(/_/g, ' ')}: ${v.join(', ')}`);
    await cfgLoad();
    cfgState(`applied${did.length ? ' (' + did.join('; ') + ')' : ' (nothing had to restart)'}${r.json && r.json.persisted ? ', saved to the file' : ', kept in memory'}`);
    await loadConfigFacts();
  } else if (r.status === 412) {
    cfgState('refused: the configuration changed since it was loaded; Load it again and redo the edit', true);
  } else {
    showIssues(r.issues);
    cfgState(`${refusal(r)}; nothing changed`, true);
  }
}

$('cfg-load').addEventListener('click', cfgLoad);
$('cfg-validate').addEventListener('click', cfgValidate);
$('cfg-apply').addEventListener('click', cfgApply);
$('cfg-validate').setAttribute('data-change', '');
$('cfg-scope').addEventListener('change', () => { $('cfg-text').value = scopeText(); C.validated = null; $('cfg-apply').disabled = true; });
$('cfg-text').addEventListener('input', () => { $('cfg-apply').disabled = true; });
$('config').addEventListener('toggle', () => { if ($('config').open && !C.text) cfgLoad(); });
