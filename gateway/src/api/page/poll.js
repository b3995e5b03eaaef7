// The polls: one request at a time, a round at most once a second (the round is in main.js);
// the status, the tags of the polled devices and open tables, diagnostics, mailboxes, the fleet.
import { API, TREND_MS, S, $, now, dur, clock, faults, isTelegramLine, urlState } from './base.js';
import { api } from './rest.js';

// --- polls -------------------------------------------------------------------------------

function connection(ok, why) {
  if (ok) { S.lastOk = Date.now(); S.failing = ''; } else S.failing = why;
  const c = $('conn');
  c.hidden = ok;
  if (!ok) {
    c.textContent = `No answer from the gateway (${why || 'no status'}): every value below is as of ${S.lastOk ? clock(S.lastOk) + ', ' + dur(Date.now() - S.lastOk) + ' ago' : 'never'}, stale.`;
  }
}

export async function pollStatus() {
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
export function openDevices() {
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
export async function pollTags(all) {
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

export async function pollDiag() {
  if (!$('diag').open || !S.status) return;
  for (const l of S.status.lines) {
    const r = await api('GET', `/lines/${encodeURIComponent(l.name)}/diag`);
    if (r.ok && r.json) S.diag[l.name] = r.json;
  }
}

export async function pollTelegrams() {
  if (!$('mailboxes').open || !S.status) return;
  for (const l of S.status.lines.filter(isTelegramLine)) {
    const r = await api('GET', `/lines/${encodeURIComponent(l.name)}/telegrams`);
    if (r.ok && r.json) S.tele[l.name] = r.json;
  }
}

/** Whether this gateway serves `GET /api/v1/fleet` (its OpenAPI document says): asked only then. */
export async function findFleet() {
  const r = await api('GET', '/openapi.json');
  S.hasFleet = !!(r.ok && r.json && r.json.paths && r.json.paths[`${API}/fleet`]);
}

export async function pollFleet() {
  if (!S.hasFleet) { S.fleet = []; return; }
  const r = await api('GET', '/fleet');
  let list = [];
  if (r.ok && r.json) {
    const j = r.json;
    list = Array.isArray(j.gateways) ? j.gateways : [];
  }
  S.fleet = Array.isArray(list) ? list : [];
}
