// The status page's ground floor: constants, the page's state (S), building elements, words for
// durations, times and STATUS words, and what the URL keeps open. Imports nothing.
export const API = '/api/v1';
export const POLL_MS = 1000;
export const TREND_MS = 10 * 60 * 1000;
export const MAX_FRAMES = 400;
export const TOKEN_KEY = 'gateway-token';
const SVG_NS = 'http://www.w3.org/2000/svg';

export const S = {
  status: null, prev: null, prevAt: 0, tags: [], trends: new Map(), config: null,
  auth: 'unknown', token: sessionStorage.getItem(TOKEN_KEY) || '', lastOk: 0, failing: '',
  skew: 0, diag: {}, tele: {}, results: {}, fleet: [], eventsSeen: {}, unreadOpen: new Set(),
};
export const $ = (id) => document.getElementById(id);
// --- small helpers ---------------------------------------------------------------------

/** An element with attributes (`on*` functions become listeners) and children. */
export function el(tag, attrs, ...kids) {
  const e = tag.startsWith('svg:') ? document.createElementNS(SVG_NS, tag.slice(4)) : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else if (k === 'cls') e.setAttribute('class', v);
    else e.setAttribute(k, v === true ? '' : v);
  }
  for (const kid of kids.flat()) {
    if (kid === undefined || kid === null || kid === false) continue;
    e.append(kid instanceof Node ? kid : String(kid));
  }
  return e;
}

/** Replaces a container's children, keeping focus and typed input on elements with the same `data-k`. */
export function swap(box, ...kids) {
  const active = document.activeElement;
  const key = active && box.contains(active) ? active.getAttribute('data-k') : null;
  const typed = {};
  for (const input of box.querySelectorAll('input[data-k], select[data-k], textarea[data-k]')) {
    typed[input.getAttribute('data-k')] = input.value;
  }
  box.replaceChildren(...kids.flat().filter((k) => k));
  for (const input of box.querySelectorAll('input[data-k], select[data-k], textarea[data-k]')) {
    const v = typed[input.getAttribute('data-k')];
    if (v !== undefined) input.value = v;
  }
  if (key) {
    const again = box.querySelector(`[data-k="${CSS.escape(key)}"]`);
    if (again) again.focus();
  }
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
export const now = () => Date.now() + S.skew;
export const plural = (n, one, many) => `${n} ${n === 1 ? one : (many || one + 's')}`;

/** A duration in words: 0.4 s, 12 s, 3 min 5 s, 2 h 5 min, 3 d 4 h. */
export function dur(ms) {
  const s = Math.max(0, ms) / 1000;
  if (s < 10) return `${s.toFixed(1)} s`;
  const t = Math.floor(s);
  if (t < 60) return `${t} s`;
  if (t < 3600) return `${Math.floor(t / 60)} min ${t % 60} s`;
  if (t < 86400) return `${Math.floor(t / 3600)} h ${Math.floor(t % 3600 / 60)} min`;
  return `${Math.floor(t / 86400)} d ${Math.floor(t % 86400 / 3600)} h`;
}
export const ms = (n) => (n >= 10000 ? `${(n / 1000).toFixed(1)} s` : `${n} ms`);
const pad = (n, w) => String(n).padStart(w || 2, '0');
export function clock(t) {
  const d = new Date(t);
  return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(d.getMilliseconds(), 3)}`;
}
/** The STATUS word as the manual writes it: 08 30h. */
export function word(w) {
  const hex = (w >> 8 & 0xff).toString(16).toUpperCase().padStart(2, '0');
  return `${hex} ${(w & 0xff).toString(16).toUpperCase().padStart(2, '0')}h`;
}
const hexBytes = (hex) => (hex.match(/../g) || []);
export const spaced = (hex, max) => {
  const b = hexBytes(hex);
  return b.slice(0, max).join(' ') + (b.length > max ? ' …' : '');
};
export const ascii = (hex) => hexBytes(hex).map((h) => {
  const c = parseInt(h, 16);
  return c >= 0x20 && c < 0x7f ? String.fromCharCode(c) : '.';
}).join('');
/** Bytes in hex, 16 a row, with the printable ASCII beside them. */
export function dump(hex) {
  const b = hexBytes(hex);
  const rows = [];
  for (let i = 0; i < b.length; i += 16) {
    const part = b.slice(i, i + 16);
    rows.push(`${i.toString(16).padStart(4, '0')}  ${part.join(' ').padEnd(47)}  ${ascii(part.join(''))}`);
  }
  return rows.join('\n') || '(no bytes)';
}
export const PROTOCOLS = {
  'modbus-master-rtu': 'Modbus master RTU', 'modbus-master-ascii': 'Modbus master ASCII',
  'modbus-slave-rtu': 'Modbus slave RTU', 'modbus-rtu-tap': 'Modbus RTU tap (listen only)',
  '3964r': '3964(R)', '3964r-tap': '3964(R) tap (listen only)', ascii: 'ASCII telegrams',
};
export const STATES = {
  starting: 'starting', running: 'running', port_closed: 'port closed', restarting: 'restarting', stopped: 'stopped',
};
export const QUALITY = {
  good: 'good', stale: 'stale', not_defined: 'not defined', off: 'off', out_of_range: 'out of range',
  rejected: 'rejected', comm_failure: 'comm failure', unknown: 'never read',
};
/** Events of a line that report a fault: every class but 00h, the CP's start-up (003 7.2). */
export const faults = (l) => l.event_counts.reduce((n, c) => n + (c.event.class ? c.count : 0), 0);
export const isTelegramLine = (l) => ['3964r', '3964r-tap', 'ascii'].includes(l.protocol);

// --- the URL keeps what is open --------------------------------------------------------

export function urlState() {
  return new URLSearchParams(location.hash.slice(1));
}
export function setUrl(key, value) {
  const p = urlState();
  if (value) p.set(key, value); else p.delete(key);
  history.replaceState(null, '', `#${p.toString()}`);
}
export function restoreOpen() {
  const p = urlState();
  if (!p.has('open')) return;
  const open = new Set(p.get('open').split(','));
  for (const d of document.querySelectorAll('main > details')) d.open = open.has(d.id);
}
export function rememberOpen() {
  const open = [...document.querySelectorAll('main > details')].filter((d) => d.open).map((d) => d.id);
  setUrl('open', open.join(','));
}
export function setCount(id, n) {
  const sum = $(id).querySelector('summary');
  let c = sum.querySelector('.count');
  if (!c) { c = el('span', { cls: 'count' }); sum.append(c); }
  c.textContent = n === null ? '' : `(${n})`;
}
