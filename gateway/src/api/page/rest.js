// Requests to the REST API of this same gateway (/api/v1), the token the user pasted (kept in
// this tab's sessionStorage only, sent as Authorization: Bearer) and the write paths in words.
import { API, S, $, plural } from './base.js';

// --- requests ----------------------------------------------------------------------------

/** One API call; the answer with its JSON (or text) and, for a refusal, the server's reason. */
export async function api(method, path, opts) {
  const o = opts || {};
  const headers = Object.assign({}, o.headers || {});
  if (method !== 'GET' && S.token) headers.Authorization = `Bearer ${S.token}`;
  let body = o.body;
  if (body !== undefined && typeof body !== 'string') {
    body = JSON.stringify(body);
    headers['Content-Type'] = 'application/json';
  }
  let res;
  try {
    res = await fetch(API + path, { method, headers, body, cache: 'no-store' });
  } catch (e) {
    return { ok: false, status: 0, reason: e.message };
  }
  const text = await res.text();
  let json = null;
  if ((res.headers.get('Content-Type') || '').startsWith('application/json')) {
    try { json = JSON.parse(text); } catch (e) { json = null; }
  }
  const out = { ok: res.ok, status: res.status, json, text, headers: res.headers };
  if (!res.ok) {
    const err = json && json.error;
    out.reason = err ? err.message : `${res.status} ${res.statusText}`;
    out.code = err ? err.code : '';
    out.issues = (err && err.issues) || [];
  }
  return out;
}
export const refusal = (r) => `refused (${r.status || 'no answer'}${r.code ? ' ' + r.code : ''}): ${r.reason}`;

// --- the token ---------------------------------------------------------------------------

export function canChange() {
  return S.auth === 'insecure' || S.auth === 'unknown' || (S.auth === 'token' && !!S.token);
}
function readOnlyWhy() {
  if (S.auth === 'locked') return 'read-only: this gateway has no REST token configured and refuses every change';
  if (S.auth === 'token' && !S.token) return 'read-only: changes need a token (paste one above)';
  return '';
}
export function showAuth() {
  const a = $('auth');
  let text = '';
  if (S.auth === 'insecure') text = 'changes open to anyone: this gateway needs no token (insecure_allow_unauthenticated_changes)';
  else if (S.auth === 'token' && S.token) text = 'token set: changes are sent with it (kept in this tab only)';
  else text = readOnlyWhy();
  a.textContent = text;
  a.classList.toggle('ro', !canChange() || S.auth === 'insecure');
  for (const b of document.querySelectorAll('[data-change]')) {
    b.disabled = !canChange();
    b.title = canChange() ? '' : readOnlyWhy();
  }
}
// --- write paths, from the configuration as written (defaults where a key is left out) ---

function writePaths(cfg) {
  const out = [];
  const mt = cfg.modbus_tcp || {};
  if (mt.enabled === false) out.push('Modbus TCP off');
  else if (mt.read_only) out.push('Modbus TCP read-only');
  else if ((mt.write_ranges || []).length) out.push(`Modbus TCP writes in ${plural(mt.write_ranges.length, 'range')}`);
  else out.push('Modbus TCP writes open' + ((mt.allowed_networks || []).length ? ' to its allowed networks' : ' to every client'));
  if (mt.tls) out.push(`Modbus/TCP Security writes by role (${Object.keys(mt.tls.roles || {}).join(', ') || 'no role'})`);
  const h = cfg.http || {};
  const tokens = Object.entries(h.tokens || {}).map(([n, t]) => `${n} ${t.role || 'admin'}`);
  if (h.token_file || h.token_env) tokens.unshift('default admin');
  if (tokens.length) { S.auth = 'token'; out.push(`REST with a token (${tokens.join(', ')})`); }
  else if (h.insecure_allow_unauthenticated_changes) { S.auth = 'insecure'; out.push('REST open to anyone, no token'); }
  else { S.auth = 'locked'; out.push('REST refuses changes (no token configured)'); }
  const z = cfg.zenoh;
  out.push(z && z.writes ? 'zenoh writes on, no token' : 'zenoh writes off');
  return out;
}

export async function loadConfigFacts() {
  const r = await api('GET', '/config');
  if (!r.ok || !r.json) return;
  S.config = r.json;
  $('writes').textContent = `writes: ${writePaths(S.config).join(' · ')}`;
  showAuth();
}
