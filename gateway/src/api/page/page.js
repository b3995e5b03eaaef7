// The status page, live. Every request goes to the REST API of this same gateway (/api/v1):
// polls one at a time at most once a second, the frame monitor as one Server-Sent Events
// stream, changes with the token the user pasted (kept in this tab's sessionStorage only).
'use strict';

(() => {
  document.documentElement.classList.add('js');
  const API = '/api/v1';
  const POLL_MS = 1000;
  const TREND_MS = 10 * 60 * 1000;
  const MAX_FRAMES = 400;
  const TOKEN_KEY = 'gateway-token';
  const SVG_NS = 'http://www.w3.org/2000/svg';

  const S = {
    status: null, prev: null, prevAt: 0, tags: [], trends: new Map(), config: null,
    auth: 'unknown', token: sessionStorage.getItem(TOKEN_KEY) || '', lastOk: 0, failing: '',
    skew: 0, diag: {}, tele: {}, results: {}, fleet: [], eventsSeen: {}, unreadOpen: new Set(),
  };
  const $ = (id) => document.getElementById(id);

  // --- small helpers ---------------------------------------------------------------------

  /** An element with attributes (`on*` functions become listeners) and children. */
  function el(tag, attrs, ...kids) {
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
  function swap(box, ...kids) {
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

  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
  const now = () => Date.now() + S.skew;
  const plural = (n, one, many) => `${n} ${n === 1 ? one : (many || one + 's')}`;

  /** A duration in words: 0.4 s, 12 s, 3 min 5 s, 2 h 5 min, 3 d 4 h. */
  function dur(ms) {
    const s = Math.max(0, ms) / 1000;
    if (s < 10) return `${s.toFixed(1)} s`;
    const t = Math.floor(s);
    if (t < 60) return `${t} s`;
    if (t < 3600) return `${Math.floor(t / 60)} min ${t % 60} s`;
    if (t < 86400) return `${Math.floor(t / 3600)} h ${Math.floor(t % 3600 / 60)} min`;
    return `${Math.floor(t / 86400)} d ${Math.floor(t % 86400 / 3600)} h`;
  }
  const ms = (n) => (n >= 10000 ? `${(n / 1000).toFixed(1)} s` : `${n} ms`);
  const pad = (n, w) => String(n).padStart(w || 2, '0');
  function clock(t) {
    const d = new Date(t);
    return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(d.getMilliseconds(), 3)}`;
  }
  /** The STATUS word as the manual writes it: 08 30h. */
  function word(w) {
    const hex = (w >> 8 & 0xff).toString(16).toUpperCase().padStart(2, '0');
    return `${hex} ${(w & 0xff).toString(16).toUpperCase().padStart(2, '0')}h`;
  }
  const hexBytes = (hex) => (hex.match(/../g) || []);
  const spaced = (hex, max) => {
    const b = hexBytes(hex);
    return b.slice(0, max).join(' ') + (b.length > max ? ' …' : '');
  };
  const ascii = (hex) => hexBytes(hex).map((h) => {
    const c = parseInt(h, 16);
    return c >= 0x20 && c < 0x7f ? String.fromCharCode(c) : '.';
  }).join('');
  /** Bytes in hex, 16 a row, with the printable ASCII beside them. */
  function dump(hex) {
    const b = hexBytes(hex);
    const rows = [];
    for (let i = 0; i < b.length; i += 16) {
      const part = b.slice(i, i + 16);
      rows.push(`${i.toString(16).padStart(4, '0')}  ${part.join(' ').padEnd(47)}  ${ascii(part.join(''))}`);
    }
    return rows.join('\n') || '(no bytes)';
  }
  const PROTOCOLS = {
    'modbus-master-rtu': 'Modbus master RTU', 'modbus-master-ascii': 'Modbus master ASCII',
    'modbus-slave-rtu': 'Modbus slave RTU', 'modbus-rtu-tap': 'Modbus RTU tap (listen only)',
    '3964r': '3964(R)', '3964r-tap': '3964(R) tap (listen only)', ascii: 'ASCII telegrams',
  };
  const STATES = {
    starting: 'starting', running: 'running', port_closed: 'port closed', restarting: 'restarting', stopped: 'stopped',
  };
  const QUALITY = {
    good: 'good', stale: 'stale', not_defined: 'not defined', off: 'off', out_of_range: 'out of range',
    rejected: 'rejected', comm_failure: 'comm failure', unknown: 'never read',
  };
  /** Events of a line that report a fault: every class but 00h, the CP's start-up (003 7.2). */
  const faults = (l) => l.event_counts.reduce((n, c) => n + (c.event.class ? c.count : 0), 0);
  const isTelegramLine = (l) => ['3964r', '3964r-tap', 'ascii'].includes(l.protocol);

  // --- the URL keeps what is open --------------------------------------------------------

  function urlState() {
    return new URLSearchParams(location.hash.slice(1));
  }
  function setUrl(key, value) {
    const p = urlState();
    if (value) p.set(key, value); else p.delete(key);
    history.replaceState(null, '', `#${p.toString()}`);
  }
  function restoreOpen() {
    const p = urlState();
    if (!p.has('open')) return;
    const open = new Set(p.get('open').split(','));
    for (const d of document.querySelectorAll('main > details')) d.open = open.has(d.id);
  }
  function rememberOpen() {
    const open = [...document.querySelectorAll('main > details')].filter((d) => d.open).map((d) => d.id);
    setUrl('open', open.join(','));
  }

  // --- requests ----------------------------------------------------------------------------

  /** One API call; the answer with its JSON (or text) and, for a refusal, the server's reason. */
  async function api(method, path, opts) {
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
  const refusal = (r) => `refused (${r.status || 'no answer'}${r.code ? ' ' + r.code : ''}): ${r.reason}`;

  // --- the token ---------------------------------------------------------------------------

  function canChange() {
    return S.auth === 'insecure' || S.auth === 'unknown' || (S.auth === 'token' && !!S.token);
  }
  function readOnlyWhy() {
    if (S.auth === 'locked') return 'read-only: this gateway has no REST token configured and refuses every change';
    if (S.auth === 'token' && !S.token) return 'read-only: changes need a token (paste one above)';
    return '';
  }
  function showAuth() {
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
  $('token-form').addEventListener('submit', (ev) => {
    ev.preventDefault();
    S.token = $('token').value.trim();
    $('token').value = '';
    if (S.token) sessionStorage.setItem(TOKEN_KEY, S.token); else sessionStorage.removeItem(TOKEN_KEY);
    showAuth();
    renderAll();
  });
  $('token-forget').addEventListener('click', () => {
    S.token = '';
    sessionStorage.removeItem(TOKEN_KEY);
    showAuth();
    renderAll();
  });

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

  async function loadConfigFacts() {
    const r = await api('GET', '/config');
    if (!r.ok || !r.json) return;
    S.config = r.json;
    $('writes').textContent = `writes: ${writePaths(S.config).join(' · ')}`;
    showAuth();
  }

  // --- polls -------------------------------------------------------------------------------

  function connection(ok, why) {
    if (ok) { S.lastOk = Date.now(); S.failing = ''; } else S.failing = why;
    const c = $('conn');
    c.hidden = ok;
    if (!ok) {
      c.textContent = `No answer from the gateway (${why || 'no status'}): every value below is as of ${S.lastOk ? clock(S.lastOk) + ', ' + dur(Date.now() - S.lastOk) + ' ago' : 'never'}, stale.`;
    }
  }

  async function pollStatus() {
    const r = await api('GET', '/status');
    if (!r.ok || !r.json) { connection(false, r.reason); return false; }
    connection(true);
    S.status = r.json; S.at = Date.now();
    // Rates over the last 5 to 10 s of statuses: steady however the rounds are spaced.
    S.hist = (S.hist || []).filter((h) => S.at - h.at < 10000);
    S.hist.push({ at: S.at, status: r.json });
    const base = S.hist.find((h) => S.at - h.at >= 5000) || S.hist[0];
    S.prev = base.status; S.prevAt = base.at;
    const serverNow = Date.parse(r.json.started) + r.json.uptime_seconds * 1000;
    const skew = serverNow - Date.now();
    S.skew = Math.abs(skew) > 2000 ? skew : 0;
    for (const l of r.json.lines) {
      const count = faults(l);
      const seen = S.eventsSeen[l.name];
      if (!seen || count < seen.count) S.eventsSeen[l.name] = { count, at: 0 };
      else if (count > seen.count) S.eventsSeen[l.name] = { count, at: Date.now() };
    }
    return true;
  }

  /** The devices whose tag tables are open (the URL keeps them); the first one at the first visit. */
  function openDevices() {
    const p = urlState();
    if (!p.has('dev')) {
      const first = S.tags.length ? `${S.tags[0].line}/${S.tags[0].device}` : '';
      return new Set(first ? [first] : []);
    }
    return new Set(p.get('dev').split(',').filter((x) => x && x !== '-'));
  }

  function remember(t) {
    const k = `${t.line}/${t.device}/${t.tag}`;
    let tr = S.trends.get(k);
    if (!tr) { tr = []; S.trends.set(k, tr); }
    const v = typeof t.value === 'boolean' ? (t.value ? 1 : 0) : t.value;
    const at = t.timestamp ? Date.parse(t.timestamp) : null;
    if (typeof v === 'number' && at && (!tr.length || tr[tr.length - 1][0] < at)) tr.push([at, v]);
    while (tr.length && tr[0][0] < now() - TREND_MS) tr.shift();
  }

  /** The devices polled each second: every device of a Modbus master line and the open tables. */
  function liveDevices() {
    const set = new Set(openDevices());
    for (const l of (S.status ? S.status.lines : [])) for (const d of l.devices) set.add(`${l.name}/${d.name}`);
    return set;
  }

  /** Every tag now and then (the list of devices, the CP memory); the devices' tags every second. */
  async function pollTags(all) {
    if (all || !S.tags.length) {
      const r = await api('GET', '/tags');
      if (r.ok && Array.isArray(r.json)) S.tags = r.json;
    }
    const live = liveDevices();
    for (const dev of live) {
      const [line, device] = dev.split('/');
      const r = await api('GET', `/tags?line=${encodeURIComponent(line)}&device=${encodeURIComponent(device)}`);
      if (!r.ok || !Array.isArray(r.json)) continue;
      const fresh = new Map(r.json.map((t) => [`${t.line}/${t.device}/${t.tag}`, t]));
      S.tags = S.tags.map((t) => fresh.get(`${t.line}/${t.device}/${t.tag}`) || t);
    }
    for (const t of S.tags) if (live.has(`${t.line}/${t.device}`)) remember(t);
  }

  async function pollDiag() {
    if (!$('diag').open || !S.status) return;
    for (const l of S.status.lines) {
      const r = await api('GET', `/lines/${encodeURIComponent(l.name)}/diag`);
      if (r.ok && r.json) S.diag[l.name] = r.json;
    }
  }

  async function pollTelegrams() {
    if (!$('mailboxes').open || !S.status) return;
    for (const l of S.status.lines.filter(isTelegramLine)) {
      const r = await api('GET', `/lines/${encodeURIComponent(l.name)}/telegrams`);
      if (r.ok && r.json) S.tele[l.name] = r.json;
    }
  }

  /** Whether this gateway serves `GET /api/v1/fleet` (its OpenAPI document says): asked only then. */
  async function findFleet() {
    const r = await api('GET', '/openapi.json');
    S.hasFleet = !!(r.ok && r.json && r.json.paths && r.json.paths[`${API}/fleet`]);
  }

  async function pollFleet() {
    if (!S.hasFleet) { S.fleet = []; return; }
    const r = await api('GET', '/fleet');
    let list = [];
    if (r.ok && r.json) {
      const j = r.json;
      list = Array.isArray(j.gateways) ? j.gateways : [];
    }
    S.fleet = Array.isArray(list) ? list : [];
  }

  async function loop() {
    let n = 0;
    for (;;) {
      const t0 = Date.now();
      if (!document.hidden) {
        if (await pollStatus()) {
          await pollTags(n % 10 === 0);
          if (n % 3 === 0) { await pollDiag(); await pollTelegrams(); }
          if (n % 15 === 0) await pollFleet();
        }
        n += 1;
        renderAll();
      }
      // At most one round a second; a section just opened asks for the next round at once.
      const wait = Math.max(200, POLL_MS - (Date.now() - t0));
      for (let t = 0; t < wait && !S.kick; t += 100) await sleep(100);
      S.kick = false;
    }
  }

  // --- rendering ---------------------------------------------------------------------------

  function renderAll() {
    if (!S.status) return;
    // The live view replaces the server's snapshot once it has something to show.
    document.documentElement.classList.add('ready');
    renderHeader();
    renderProblems();
    renderFleet();
    renderLines();
    renderDevices();
    renderTags();
    renderMailboxes();
    renderDiag();
    fillLineSelects();
    showAuth();
  }

  function renderHeader() {
    const s = S.status;
    const z = s.zenoh ? `zenoh ${s.zenoh.mode} ${s.zenoh.up ? 'up' : 'down'}, ${plural(s.zenoh.publications_total, 'publication')}` : 'zenoh off';
    const mt = s.modbus_tcp;
    swap($('gw'), el('span', {}, s.name), el('span', { cls: 'sep' }, ' · '), `version ${s.version}`,
      el('span', { cls: 'sep' }, ' · '), `up ${dur(s.uptime_seconds * 1000)}`, el('span', { cls: 'sep' }, ' · '),
      `Modbus TCP ${mt.up ? plural(mt.connections, 'client') : 'down'}`, el('span', { cls: 'sep' }, ' · '), z,
      el('span', { cls: 'sep' }, ' · '), s.ready ? 'ready' : el('span', { cls: 'bad' }, 'not ready'));
    document.title = `${s.name} · gateway status`;
  }

  function lineEventItem(l, cls) {
    const e = l.last_event;
    return el('li', { cls },
      el('b', {}, `${l.name}: `), el('span', { cls: 'word' }, word(e.status_word)), ` ${e.class_name}: ${e.description}`,
      e.detail ? ` (${e.detail})` : '',
      el('span', { cls: 'remedy' }, `Remedy: ${e.remedy || 'the manual gives none'}`));
  }

  function renderProblems() {
    const s = S.status;
    const items = [];
    for (const l of s.lines) {
      if (l.state !== 'running') {
        items.push(el('li', {}, el('b', {}, `${l.name}: `), `${STATES[l.state] || l.state}`, l.port_error ? ` — ${l.port_error}` : ''));
      }
    }
    for (const l of s.lines) {
      for (const d of l.devices.filter((x) => !x.online)) {
        const since = d.last_answer ? `offline, last answer ${clock(Date.parse(d.last_answer))} (${dur(now() - Date.parse(d.last_answer))} ago)` : 'offline, never answered';
        items.push(el('li', {}, el('b', {}, `${l.name} / ${d.name}: `), `${since}; unit ${d.unit_id}, address ${d.address}`,
          l.last_event ? el('span', { cls: 'remedy' }, `${word(l.last_event.status_word)} ${l.last_event.description} Remedy: ${l.last_event.remedy || 'none given'}`) : ''));
      }
    }
    for (const l of s.lines) {
      const seen = S.eventsSeen[l.name];
      if (l.last_event && l.last_event.class && seen && seen.at && Date.now() - seen.at < 60000) items.push(lineEventItem(l, ''));
    }
    // Never read: a tag of the device's profile that no poll reads (not a fault).
    const stale = S.tags.filter((t) => t.quality !== 'good' && t.quality !== 'unknown');
    if (stale.length) {
      const names = stale.slice(0, 6).map((t) => `${t.line}/${t.device}/${t.tag} ${QUALITY[t.quality] || t.quality}`);
      items.push(el('li', { cls: 'warn' }, `${plural(stale.length, 'value')} not good: ${names.join(', ')}${stale.length > 6 ? ', …' : ''}`));
    }
    if (S.auth === 'insecure') items.push(el('li', { cls: 'warn' }, 'REST changes are open to anyone without a token (insecure_allow_unauthenticated_changes)'));
    const mt = (S.config && S.config.modbus_tcp) || {};
    if (S.config && mt.enabled !== false && !mt.read_only && !(mt.write_ranges || []).length && !(mt.allowed_networks || []).length) {
      items.push(el('li', { cls: 'warn' }, 'Modbus TCP writes are open to every client (no read_only, write_ranges or allowed_networks)'));
    }
    if (s.zenoh && s.zenoh.name_conflict) items.push(el('li', {}, el('b', {}, 'zenoh: '), `this gateway's name is held by another session, so it publishes nothing on zenoh until the name is free: ${s.zenoh.name_conflict}`));
    if (S.config && S.config.zenoh && S.config.zenoh.writes) items.push(el('li', { cls: 'warn' }, 'zenoh writes are on: any zenoh peer may write tags and send telegrams'));
    const body = $('problems').querySelector('.body');
    swap(body, items.length ? el('ul', { cls: 'problems' }, items) : el('p', { cls: 'ok' }, 'No problem: every line runs, every device answers, every value is good.'));
    setCount('problems', items.length);
  }

  function setCount(id, n) {
    const sum = $(id).querySelector('summary');
    let c = sum.querySelector('.count');
    if (!c) { c = el('span', { cls: 'count' }); sum.append(c); }
    c.textContent = n === null ? '' : `(${n})`;
  }

  /** A plain http(s)://host:port URL, with an optional / at the end: the only fleet address shown as a link. */
  const PLAIN_URL = /^https?:\/\/([A-Za-z0-9][A-Za-z0-9.-]{0,252}|\[[0-9A-Fa-f:.]+\]):[0-9]{1,5}\/?$/;

  function renderFleet() {
    const f = $('fleet');
    f.hidden = !S.fleet.length;
    if (!S.fleet.length) return;
    // GET /api/v1/fleet: {gateways: [{key, name, zid, host, online, since, http, link}]}. Every
    // text is a peer's, bounded by the gateway and shown as text; a link only for a plain
    // http(s)://host:port URL (no user, path, query or fragment), anything else as text.
    const rows = S.fleet.slice(0, 256).map((g) => {
      const name = String(g.name || g.key || '?');
      const link = g.link;
      const page = typeof link === 'string' && PLAIN_URL.test(link) ? el('a', { href: link, rel: 'noopener noreferrer' }, `open ${name}'s page`)
        : (typeof g.http === 'string' && g.http ? el('span', { cls: 'text-url' }, g.http) : 'no page');
      const state = g.online ? 'online' : 'gone';
      const since = g.since ? `${state} for ${dur(now() - Date.parse(g.since))}` : state;
      return el('tr', {}, el('th', { scope: 'row' }, name), el('td', {}, since),
        el('td', {}, g.host || ''), el('td', {}, page));
    });
    swap(f.querySelector('.body'), el('table', {}, el('thead', {}, el('tr', {},
      ['gateway', 'state', 'host', 'page'].map((h) => el('th', { scope: 'col' }, h)))), el('tbody', {}, rows)));
    setCount('fleet', S.fleet.length);
  }

  function rate(l, pick) {
    if (!S.prev || !S.prevAt || S.at - S.prevAt < 900) return null;
    const p = S.prev.lines.find((x) => x.name === l.name);
    if (!p || p.started !== l.started) return null;
    const dt = (S.at - S.prevAt) / 1000;
    return dt > 0 ? Math.max(0, (pick(l) - pick(p)) / dt) : null;
  }
  const perSec = (v, unit) => (v === null ? '—' : `${v < 10 ? v.toFixed(1) : Math.round(v)} ${unit}/s`);

  function renderLines() {
    const rows = S.status.lines.map((l) => {
      const e = l.last_event;
      const classes = {};
      for (const c of l.event_counts) {
        const k = `${c.event.class.toString(16).toUpperCase().padStart(2, '0')}h ${c.event.class_name}`;
        classes[k] = (classes[k] || 0) + c.count;
      }
      const frames = rate(l, (x) => x.counters.frames_sent + x.counters.frames_received);
      const errors = rate(l, faults);
      const bad = l.state !== 'running';
      return el('tr', { cls: bad ? 'bad' : '', 'data-line': l.name },
        el('th', { scope: 'row' }, l.name),
        el('td', {}, PROTOCOLS[l.protocol] || l.protocol),
        el('td', { cls: 'mono small' }, l.port, l.port_b ? ` + ${l.port_b}` : ''),
        el('td', { cls: bad ? 'bad' : 'ok' }, STATES[l.state] || l.state, l.port_error ? el('span', { cls: 'result' }, l.port_error) : ''),
        el('td', {}, e ? [el('span', { cls: 'word' }, word(e.status_word)), ` ${e.class_name}: ${e.description}`,
          e.class ? el('span', { cls: 'result remedy' }, `Remedy: ${e.remedy || 'the manual gives none'}`) : ''] : el('span', { cls: 'muted' }, '00 00h no event')),
        el('td', { cls: 'small' }, Object.keys(classes).length ? Object.entries(classes).map(([k, n]) => el('span', { cls: 'result' }, `${k}: ${n}`)) : 'none'),
        el('td', { cls: 'num' }, perSec(frames, 'frames')),
        el('td', { cls: 'num' }, perSec(errors, 'faults')));
    });
    swap($('lines').querySelector('.body'), el('div', { cls: 'scroll' }, el('table', {},
      el('thead', {}, el('tr', {}, ['line', 'protocol', 'port', 'state', 'STATUS of the last event', 'events per class', 'frames', 'fault events']
        .map((h) => el('th', { scope: 'col' }, h)))), el('tbody', {}, rows))));
    setCount('lines', S.status.lines.length);
  }

  function deviceTags(line, device) {
    return S.tags.filter((t) => t.line === line && t.device === device);
  }

  function renderDevices() {
    const rows = [];
    for (const l of S.status.lines) {
      for (const d of l.devices) {
        const tags = deviceTags(l.name, d.name).filter((t) => t.timestamp);
        const oldest = tags.length ? Math.max(...tags.map((t) => now() - Date.parse(t.timestamp))) : null;
        const cycles = (d.cycles || []).map((c) => {
          const over = c.achieved_max_ms !== undefined && c.achieved_max_ms > c.bound_ms;
          return el('span', { cls: `result${over ? ' bad' : ''}` },
            `${c.table} ${c.start} ×${c.count}: every ${ms(c.planned_ms)}, last ${c.achieved_ms === undefined ? '—' : ms(c.achieved_ms)}, ` +
            `longest ${c.achieved_max_ms === undefined ? '—' : ms(c.achieved_max_ms)} (bound ${ms(c.bound_ms)}${over ? ', over its bound' : ''})`);
        });
        rows.push(el('tr', { cls: d.online ? '' : 'bad' },
          el('th', { scope: 'row' }, `${l.name} / ${d.name}`),
          el('td', { cls: 'num' }, `unit ${d.unit_id}, address ${d.address}`),
          el('td', { cls: d.online ? 'ok' : 'bad' }, d.online ? 'online' : 'offline'),
          el('td', { cls: 'num' }, oldest === null ? 'no value yet' : dur(oldest)),
          el('td', { cls: 'small' }, `${d.polls_ok} ok, ${d.polls_exception} exception answers, ${d.polls_failed} without answer`,
            d.commands_failed ? `, ${d.commands_failed} commands failed` : '',
            d.last_answer ? el('span', { cls: 'result muted' }, `last answer ${dur(now() - Date.parse(d.last_answer))} ago`) : ''),
          el('td', { cls: 'small' }, cycles.length ? cycles : 'no poll')));
      }
    }
    swap($('devices').querySelector('.body'), rows.length ? el('div', { cls: 'scroll' }, el('table', {},
      el('thead', {}, el('tr', {}, ['device', 'unit', 'state', 'oldest value', 'polls', 'poll cycle against its bound']
        .map((h) => el('th', { scope: 'col' }, h)))), el('tbody', {}, rows))) : el('p', { cls: 'muted' }, 'No polled device.'));
    setCount('devices', rows.length);
  }

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
  function renderTags() {
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

  function renderMailboxes() {
    const lines = S.status.lines.filter(isTelegramLine);
    const det = $('mailboxes');
    setCount('mailboxes', lines.length);
    // Not while a telegram is being typed: the list follows when the field is left.
    if (!det.open || (det.contains(document.activeElement) && document.activeElement.tagName === 'INPUT')) return;
    const blocks = lines.map((l) => {
      const q = S.tele[l.name];
      const res = S.results[`tele/${l.name}`];
      const list = q ? q.telegrams : [];
      const rows = list.slice(0, 10).map((t, i) => el('tr', {},
        el('td', { cls: 'num' }, t.seq), el('td', { cls: 'num' }, clock(Date.parse(t.received))),
        el('td', { cls: 'num' }, `${t.len} B`), el('td', { cls: 'hex' }, spaced(t.hex, 24)),
        el('td', { cls: 'mono' }, t.text !== undefined ? JSON.stringify(t.text) : ascii(t.hex)),
        el('td', {}, t.side ? `side ${t.side}` : '', i === 0 ? el('button', { type: 'button', 'data-change': true, 'data-k': `ack-${l.name}`, onclick: () => ack(l.name, t.seq) }, `Acknowledge ${t.seq}`) : '')));
      const send = l.protocol === '3964r-tap' ? el('p', { cls: 'muted' }, 'a tap line listens only: it sends nothing') :
        el('form', { cls: 'bar', onsubmit: (ev) => { ev.preventDefault(); sendTelegram(l.name, ev.target); } },
          el('label', {}, 'send ', el('select', { name: 'kind', 'data-k': `kind-${l.name}` }, el('option', { value: 'text' }, 'text'), el('option', { value: 'hex' }, 'hex bytes'))),
          el('label', { cls: 'sr', for: `send-${l.name}` }, `telegram to send on ${l.name}`),
          el('input', { id: `send-${l.name}`, name: 'data', 'data-k': `send-${l.name}`, size: 24, autocomplete: 'off' }),
          el('button', { type: 'submit', 'data-change': true, 'data-k': `sendb-${l.name}` }, 'Send'));
      return el('div', { cls: 'mail' }, el('h3', {}, `${l.name} `, el('span', { cls: 'muted' },
        q ? `${plural(list.length, 'telegram')} waiting (room for ${q.capacity}), ${q.dropped} dropped because the queue was full` : 'not read yet')),
        rows.length ? el('div', { cls: 'scroll' }, el('table', {}, el('thead', {}, el('tr', {},
          ['seq', 'received', 'length', 'bytes (hex)', 'text', ''].map((h) => el('th', { scope: 'col' }, h)))), el('tbody', {}, rows),
          list.length > 10 ? el('tfoot', {}, el('tr', {}, el('td', { colspan: 6, cls: 'muted' }, `and ${plural(list.length - 10, 'newer telegram')}, acknowledged in order`))) : '')) : el('p', { cls: 'muted' }, 'no telegram waiting'),
        send, res ? el('span', { cls: `result ${res.ok ? 'ok' : 'refused'}`, role: 'status' }, res.text) : '');
    });
    swap(det.querySelector('.body'), blocks.length ? blocks : el('p', { cls: 'muted' }, 'No telegram line.'));
  }

  async function ack(line, seq) {
    const r = await api('POST', `/lines/${encodeURIComponent(line)}/telegrams/${seq}/ack`);
    S.results[`tele/${line}`] = r.ok ? { ok: true, text: `telegram ${seq} acknowledged` } : { ok: false, text: refusal(r) };
    await pollTelegrams();
    renderMailboxes();
  }

  async function sendTelegram(line, form) {
    const kind = form.elements.kind.value;
    const data = form.elements.data.value;
    const r = await api('POST', `/lines/${encodeURIComponent(line)}/send`, { body: kind === 'hex' ? { hex: data } : { text: data } });
    let text;
    if (r.ok) {
      const j = r.json || {};
      text = j.done ? `sent ${j.len} B: done` : `not done: ${word(j.status_word || 0)} ${j.event ? j.event.description + '. Remedy: ' + (j.event.remedy || 'none given') : ''}`;
      S.results[`tele/${line}`] = { ok: !!j.done, text };
    } else S.results[`tele/${line}`] = { ok: false, text: refusal(r) };
    renderMailboxes();
  }

  function renderDiag() {
    const det = $('diag');
    if (!det.open) return;
    const blocks = S.status.lines.map((l) => {
      const d = S.diag[l.name];
      const res = S.results[`diag/${l.name}`];
      const rows = d ? d.entries.map((e) => el('tr', {},
        el('td', { cls: 'num' }, clock(Date.parse(e.time))),
        el('td', { cls: 'word' }, word(e.status_word)),
        el('td', {}, e.class_name),
        el('td', {}, e.description, e.detail ? ` (${e.detail})` : '', e.class ? el('span', { cls: 'result remedy' }, `Remedy: ${e.remedy || 'the manual gives none'}`) : ''))) : [];
      return el('div', { cls: 'mail' }, el('h3', {}, `${l.name} `, el('span', { cls: 'muted' }, d ? `${plural(d.entries.length, 'entry', 'entries')} of ${d.depth}, newest first` : 'not read yet')),
        rows.length ? el('div', { cls: 'scroll' }, el('table', {}, el('thead', {}, el('tr', {},
          ['time', 'STATUS', 'class', 'description and remedy'].map((h) => el('th', { scope: 'col' }, h)))), el('tbody', {}, rows))) : el('p', { cls: 'muted' }, 'empty'),
        el('button', { type: 'button', 'data-change': true, 'data-k': `clear-${l.name}`, onclick: () => clearDiag(l.name) }, `Clear the buffer of ${l.name}`),
        res ? el('span', { cls: `result ${res.ok ? 'ok' : 'refused'}`, role: 'status' }, res.text) : '');
    });
    swap(det.querySelector('.body'), blocks);
  }

  async function clearDiag(line) {
    const r = await api('DELETE', `/lines/${encodeURIComponent(line)}/diag`);
    S.results[`diag/${line}`] = r.ok ? { ok: true, text: `cleared at ${clock(Date.now())}` } : { ok: false, text: refusal(r) };
    await pollDiag();
    renderDiag();
  }

  function fillLineSelects() {
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

  function monitorStop() {
    if (M.source) { M.source.close(); M.source = null; }
    if (M.retry) { clearTimeout(M.retry); M.retry = null; }
  }

  function monitorStart() {
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

  async function cfgLoad() {
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

  // --- start -------------------------------------------------------------------------------

  restoreOpen();
  for (const d of document.querySelectorAll('main > details')) d.addEventListener('toggle', () => { rememberOpen(); S.kick = true; renderAll(); });
  document.addEventListener('visibilitychange', () => {
    if (document.hidden) monitorStop(); else if ($('frames').open) monitorStart();
  });
  showAuth();
  (async () => {
    await loadConfigFacts();
    await findFleet();
    if ($('config').open) cfgLoad();
    loop();
  })();
})();
