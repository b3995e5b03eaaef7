// The sections that give the overview: the header, problems, fleet, lines and devices.
import { S, $, el, swap, now, plural, dur, ms, clock, word, PROTOCOLS, STATES, QUALITY, faults, setCount } from './base.js';

export function renderHeader() {
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

export function renderProblems() {
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

/** A plain http(s)://host:port URL, with an optional / at the end: the only fleet address shown as a link. */
const PLAIN_URL = /^https?:\/\/([A-Za-z0-9][A-Za-z0-9.-]{0,252}|\[[0-9A-Fa-f:.]+\]):[0-9]{1,5}\/?$/;

export function renderFleet() {
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

export function renderLines() {
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

export function renderDevices() {
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
