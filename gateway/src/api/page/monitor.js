// The frame monitor: one Server-Sent Events stream at a time, of the chosen line, only while
// the section is open and the tab visible.
import { API, MAX_FRAMES, S, $, el, swap, plural, clock, spaced, dump, urlState, setUrl } from './base.js';

export function fillLineSelects() {
  const names = S.status.lines.map((l) => l.name);
  for (const [id, first] of [['mon-line', null], ['cfg-scope', ['', 'the whole file']]]) {
    const sel = $(id);
    const have = [...sel.options].map((o) => o.value).filter((v) => v !== '');
    if (have.join() === names.join()) continue;
    const keep = sel.value;
    sel.replaceChildren(...(first ? [el('option', { value: first[0] }, first[1])] : []),
      ...names.map((n) => el('option', { value: n }, id === 'cfg-scope' ? `line ${n}` : n)));
    if (keep) sel.value = keep;
    if (id === 'mon-line' && !sel.value) sel.value = urlState().get('mon') || names[0] || '';
    if (id === 'mon-line' && urlState().get('mon') && names.includes(urlState().get('mon'))) sel.value = urlState().get('mon');
  }
  if ($('frames').open && !M.source && !M.retry) monitorStart();
}

// --- the frame monitor: one SSE stream at a time -----------------------------------------

const M = { source: null, line: '', last: 0, paused: false, hover: false, held: [], retry: null, selected: null };

export function monitorStop() {
  if (M.source) { M.source.close(); M.source = null; }
  if (M.retry) { clearTimeout(M.retry); M.retry = null; }
}

export function monitorStart() {
  monitorStop();
  const line = $('mon-line').value;
  if (!line || !$('frames').open) { $('mon-state').textContent = 'stopped'; return; }
  if (line !== M.line) { M.line = line; M.last = 0; M.held = []; $('mon-rows').replaceChildren(); closeDetail(); }
  setUrl('mon', line);
  $('mon-capture').href = `${API}/lines/${encodeURIComponent(line)}/capture`;
  $('mon-capture').setAttribute('download', `${line}.pcapng`);
  const src = new EventSource(`${API}/lines/${encodeURIComponent(line)}/frames?follow=true&since=${M.last}`);
  M.source = src;
  $('mon-state').textContent = `connecting to ${line}…`;
  src.addEventListener('open', () => { $('mon-state').textContent = `live: ${line}`; });
  src.addEventListener('frame', (ev) => {
    let f;
    try { f = JSON.parse(ev.data); } catch (e) { return; }
    if (f.seq <= M.last) return;
    M.last = f.seq;
    if (M.paused || M.hover) { M.held.push(f); if (M.held.length > MAX_FRAMES) M.held.shift(); showHeld(); } else addFrames([f]);
  });
  src.addEventListener('lagged', (ev) => { $('mon-state').textContent = `live: ${line} (${ev.data} frames missed: the page fell behind)`; });
  src.addEventListener('error', () => {
    // One stream at a time: closed here, opened again from the last frame seen.
    src.close();
    if (M.source !== src) return;
    M.source = null;
    $('mon-state').textContent = `stream of ${line} interrupted: trying again in 3 s`;
    M.retry = setTimeout(() => { M.retry = null; monitorStart(); }, 3000);
  });
}

function showHeld() {
  const why = M.paused ? 'paused' : 'held while the pointer is on the list';
  $('mon-state').textContent = `${why}: ${plural(M.held.length, 'new frame')} waiting`;
}

function frameVisible(f) {
  const dir = $('mon-dir').value; const v = $('mon-verdict').value;
  if (dir && f.direction !== dir) return false;
  if (v === '!ok') return f.verdict !== 'ok' && f.verdict !== 'control';
  return !v || f.verdict === v;
}

function frameRow(f) {
  const bad = !['ok', 'control', 'raw'].includes(f.verdict);
  const row = el('tr', { tabindex: 0, cls: bad ? 'bad' : '', 'data-seq': f.seq, 'data-first-us': f.first_us, 'data-dir': f.direction, 'data-verdict': f.verdict,
    onclick: () => openDetail(f, row), onkeydown: (ev) => frameKey(ev, f, row) },
  el('td', { cls: 'num' }, clock(f.first_us / 1000)), el('td', {}, f.direction), el('td', { cls: 'num' }, `${f.length} B`),
  el('td', { cls: 'hex' }, spaced(f.bytes, 12)), el('td', { cls: bad ? 'bad' : '' }, f.verdict),
  el('td', { cls: 'sum' }, f.summary, f.errors.length ? ` · line errors: ${f.errors.map((e) => `${e.error} before byte ${e.offset}`).join(', ')}` : ''));
  row.frame = f;
  row.hidden = !frameVisible(f);
  return row;
}

/** Enter or Space opens a frame; the arrow keys move to the next or previous frame shown. */
function frameKey(ev, f, row) {
  if (ev.key === 'Enter' || ev.key === ' ') { ev.preventDefault(); openDetail(f, row); return; }
  const step = { ArrowDown: 'nextElementSibling', ArrowUp: 'previousElementSibling' }[ev.key];
  if (!step) return;
  ev.preventDefault();
  let next = row[step];
  while (next && next.hidden) next = next[step];
  if (next) next.focus();
}

function addFrames(frames) {
  const body = $('mon-rows');
  const box = $('mon-scroll');
  const atBottom = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;
  body.append(...frames.map(frameRow));
  while (body.children.length > MAX_FRAMES) body.firstElementChild.remove();
  if (atBottom) box.scrollTop = box.scrollHeight;
  if (M.source) $('mon-state').textContent = `live: ${M.line}, ${plural(body.children.length, 'frame')} shown`;
}

function releaseHeld() {
  if (M.paused || M.hover || !M.held.length) return;
  const held = M.held; M.held = [];
  addFrames(held);
}

function openDetail(f, row) {
  for (const r of document.querySelectorAll('#mon-rows tr[aria-selected]')) r.removeAttribute('aria-selected');
  row.setAttribute('aria-selected', 'true');
  M.selected = row;
  const d = $('mon-detail');
  d.hidden = false;
  swap(d, el('p', {}, el('b', {}, `frame ${f.seq}`), ` · ${f.direction} · ${clock(f.first_us / 1000)} to ${clock(f.last_us / 1000)} · ${f.length} B · ${f.verdict}`),
    el('p', {}, f.summary), el('pre', { cls: 'dump' }, dump(f.bytes)),
    el('button', { type: 'button', onclick: closeDetail }, 'Close (Esc)'));
}

function closeDetail() {
  const d = $('mon-detail');
  d.hidden = true;
  if (M.selected) { M.selected.removeAttribute('aria-selected'); M.selected.focus(); M.selected = null; }
}

function setPaused(p) {
  M.paused = p;
  $('mon-pause').setAttribute('aria-pressed', String(p));
  $('mon-pause').textContent = p ? 'Resume (p)' : 'Pause (p)';
  if (p) showHeld(); else releaseHeld();
}

$('mon-line').addEventListener('change', () => monitorStart());
$('mon-pause').addEventListener('click', () => setPaused(!M.paused));
for (const id of ['mon-dir', 'mon-verdict']) {
  $(id).addEventListener('change', () => {
    for (const r of $('mon-rows').children) r.hidden = !frameVisible(r.frame);
  });
}
$('mon-scroll').addEventListener('mouseenter', () => { M.hover = true; });
$('mon-scroll').addEventListener('mouseleave', () => { M.hover = false; releaseHeld(); });
$('frames').addEventListener('toggle', () => { if ($('frames').open) monitorStart(); else { monitorStop(); $('mon-state').textContent = 'stopped (section closed)'; } });

document.addEventListener('keydown', (ev) => {
  const t = ev.target;
  const typing = t && (t.tagName === 'INPUT' || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT');
  if (ev.key === 'Escape' && !$('mon-detail').hidden) { closeDetail(); return; }
  if (!typing && ev.key === 'p' && $('frames').open) setPaused(!M.paused);
});
