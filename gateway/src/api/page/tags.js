// The tags, a table per device with value, quality and age, a trend and a write field.
import { S, $, el, swap, now, plural, dur, clock, QUALITY, setUrl, setCount } from './base.js';
import { api, refusal } from './rest.js';
import { openDevices } from './poll.js';

function spark(key) {
  const tr = (S.trends.get(key) || []);
  if (tr.length < 2) return el('span', { cls: 'muted small' }, 'trend from now on');
  const t0 = tr[0][0]; const t1 = tr[tr.length - 1][0];
  let lo = Infinity; let hi = -Infinity;
  for (const [, v] of tr) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  const w = 120; const h = 24;
  const pts = tr.map(([t, v]) => `${((t - t0) / Math.max(1, t1 - t0) * (w - 2) + 1).toFixed(1)},${(hi === lo ? h / 2 : (h - 2) - (v - lo) / (hi - lo) * (h - 4)).toFixed(1)}`);
  const label = `trend of the last ${dur(t1 - t0)}: from ${lo} to ${hi}`;
  return el('svg:svg', { cls: 'spark', viewBox: `0 0 ${w} ${h}`, role: 'img', 'aria-label': label },
    el('svg:title', {}, label), el('svg:polyline', { points: pts.join(' ') }));
}

function showValue(t) {
  if (t.value === null || t.value === undefined) return '—';
  const v = typeof t.value === 'string' ? `"${t.value}"` : String(t.value);
  return t.unit ? `${v} ${t.unit}` : v;
}

/** A tag's row: its write field stays while the other cells are updated in place. */
function tagRow(t) {
  const key = `${t.line}/${t.device}/${t.tag}`;
  let write = '';
  if (t.writable) {
    write = el('form', { cls: 'inline', 'data-tag': key, onsubmit: (ev) => { ev.preventDefault(); writeTag(row.tag, ev.target); } },
      el('label', { cls: 'sr', for: `w-${key}` }, `new value of ${t.tag}`),
      el('input', { id: `w-${key}`, name: 'value', 'data-k': `in-${key}`, size: 8, autocomplete: 'off' }),
      el('button', { type: 'submit', 'data-change': true, 'data-k': `wr-${key}` }, 'Write'));
  }
  const row = el('tr', { 'data-tag': key },
    el('th', { scope: 'row', cls: 'mono' }, t.tag),
    el('td', { cls: 'num value' }), el('td', { cls: 'quality' }), el('td', { cls: 'hide-narrow trend' }),
    el('td', {}, write, el('span', { cls: 'result', role: 'status' })));
  updateTagRow(row, t);
  return row;
}

function updateTagRow(row, t) {
  const key = `${t.line}/${t.device}/${t.tag}`;
  row.tag = t;
  const age = t.timestamp ? dur(now() - Date.parse(t.timestamp)) : '';
  const offline = !!S.failing;
  const q = offline ? `stale (no answer from the gateway), ${age}` : `${QUALITY[t.quality] || t.quality}${age ? ', ' + age : ''}`;
  const good = (t.quality === 'good' || t.quality === 'unknown') && !offline;
  row.className = good ? '' : 'stale';
  row.setAttribute('data-ts', t.timestamp || '');
  row.querySelector('td.value').textContent = showValue(t);
  const qc = row.querySelector('td.quality');
  qc.className = `quality ${t.quality === 'unknown' ? 'muted' : good ? 'ok' : 'warn'}`;
  qc.textContent = good ? q : `⚠ ${q}`;
  row.querySelector('td.trend').replaceChildren(spark(key));
  const res = S.results[key];
  const r = row.querySelector('span.result');
  r.className = `result${res ? (res.ok ? ' ok' : ' refused') : ''}`;
  r.textContent = res ? res.text : '';
}

function tagTable(tags) {
  return el('div', { cls: 'scroll' }, el('table', { cls: 'tags' },
    el('thead', {}, el('tr', {}, ['tag', 'value', 'quality, age', 'trend', 'write'].map((h, j) => el('th', { scope: 'col', cls: j === 3 ? 'hide-narrow' : '' }, h)))),
    el('tbody', {}, tags.map(tagRow))));
}

/** What a device's block shows: whether open, and which tags are read and which are not. */
const shape = (tags, isOpen) => `${isOpen}|${tags.map((t) => `${t.tag}:${t.quality === 'unknown' ? 'u' : 'r'}`).join(',')}`;

function tagGroup(k, tags, isOpen) {
  const read = tags.filter((t) => t.quality !== 'unknown').length;
  const d = el('details', { cls: 'dev', 'data-dev': k, 'data-shape': shape(tags, isOpen), open: isOpen },
    el('summary', { 'data-k': `sum-${k}` }, el('h3', { cls: 'sr' }, k), `${k} `,
      el('span', { cls: 'muted' }, `${plural(tags.length, 'tag')}, ${read} read`)),
    isOpen ? tagTable(tags.filter((t) => t.quality !== 'unknown')) : '',
    isOpen && read < tags.length ? el('details', { cls: 'unread', open: S.unreadOpen.has(k), ontoggle: (ev) => { if (ev.target.open) S.unreadOpen.add(k); else S.unreadOpen.delete(k); } },
      el('summary', { 'data-k': `unread-${k}` }, `${plural(tags.length - read, 'tag')} that no poll reads (never read; a write or a GET of the tag reads it)`),
      tagTable(tags.filter((t) => t.quality === 'unknown'))) : '');
  d.addEventListener('toggle', () => {
    if (d.open === isOpen) return;
    const list = [...document.querySelectorAll('#tags details.dev')].filter((x) => x.open).map((x) => x.getAttribute('data-dev'));
    setUrl('dev', list.join(',') || '-');
    if (d.open) S.kick = true;
    renderTags();
  });
  return d;
}

/** Rebuilds only what changed shape; otherwise updates the rows in place (typing is never disturbed). */
export function renderTags() {
  const body = $('tags').querySelector('.body');
  const open = openDevices();
  const groups = new Map();
  for (const t of S.tags) {
    const k = `${t.line}/${t.device}`;
    if (!groups.has(k)) groups.set(k, []);
    groups.get(k).push(t);
  }
  const old = new Map([...body.querySelectorAll(':scope > details.dev')].map((d) => [d.getAttribute('data-dev'), d]));
  setCount('tags', S.tags.length);
  if ([...groups.keys()].join('\n') !== [...old.keys()].join('\n')) {
    swap(body, groups.size ? [...groups.entries()].map(([k, tags]) => tagGroup(k, tags, open.has(k))) : el('p', { cls: 'muted' }, 'No tag.'));
    return;
  }
  for (const [k, tags] of groups) {
    const d = old.get(k);
    if (d.getAttribute('data-shape') !== shape(tags, open.has(k))) {
      const focused = d.contains(document.activeElement) ? document.activeElement.getAttribute('data-k') : null;
      const fresh = tagGroup(k, tags, open.has(k));
      d.replaceWith(fresh);
      const again = focused && fresh.querySelector(`[data-k="${CSS.escape(focused)}"]`);
      if (again) again.focus();
      continue;
    }
    if (!open.has(k)) continue;
    for (const t of tags) {
      const row = d.querySelector(`tr[data-tag="${CSS.escape(`${t.line}/${t.device}/${t.tag}`)}"]`);
      if (row) updateTagRow(row, t);
    }
  }
}

function parseValue(t, text) {
  const s = text.trim();
  if (typeof t.value === 'boolean') {
    if (/^(true|1|on)$/i.test(s)) return true;
    if (/^(false|0|off)$/i.test(s)) return false;
  }
  if (typeof t.value === 'string') return text;
  if (s !== '' && !Number.isNaN(Number(s))) return Number(s);
  return text;
}

async function writeTag(t, form) {
  const key = `${t.line}/${t.device}/${t.tag}`;
  const input = form.querySelector('input');
  const value = parseValue(t, input.value);
  const path = `/lines/${encodeURIComponent(t.line)}/devices/${encodeURIComponent(t.device)}/tags/${encodeURIComponent(t.tag)}`;
  S.results[key] = { ok: true, text: 'writing…' };
  renderTags();
  const r = await api('PUT', path, { body: { value } });
  if (r.ok) {
    S.results[key] = { ok: true, text: `written: the device answered ${showValue(r.json)} at ${clock(Date.now())}` };
    const i = S.tags.findIndex((x) => x.line === t.line && x.device === t.device && x.tag === t.tag);
    if (i >= 0 && r.json) S.tags[i] = r.json;
    const again = document.querySelector(`input[data-k="${CSS.escape('in-' + key)}"]`);
    if (again) again.value = '';
  } else {
    S.results[key] = { ok: false, text: refusal(r) };
  }
  renderTags();
}
