// The telegram mailboxes (acknowledge, send) and the diagnostic buffers (clear) of each line.
import { S, $, el, swap, plural, clock, word, spaced, ascii, isTelegramLine, setCount } from './base.js';
import { api, refusal } from './rest.js';
import { pollDiag, pollTelegrams } from './poll.js';

export function renderMailboxes() {
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

export function renderDiag() {
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
