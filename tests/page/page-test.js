// Drives the gateway's status page in Debian's Chromium (playwright-core, pinned in
// package.json; never a downloaded browser). Started by tests/tests/page.rs against a running
// `gateway demo --token-file FILE`:
//
//   GATEWAY_URL=http://127.0.0.1:PORT PAGE_TOKEN=... SCREENSHOT_DIR=target/page node page-test.js
//
// Prints one line per check with what it measured; exits 1 with the reason at the first check
// that fails.
'use strict';

const path = require('path');
const fs = require('fs');
const { chromium } = require('playwright-core');

const BASE = process.env.GATEWAY_URL;
const TOKEN = process.env.PAGE_TOKEN;
const SHOTS = process.env.SCREENSHOT_DIR;
const README_SHOT = process.env.README_SCREENSHOT;
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--no-first-run'];

function fail(msg) { throw new Error(msg); }
function check(ok, msg) { if (!ok) fail(msg); }
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const log = (what) => console.log(`page-test: ${what}`);

/** `probe` every `every` ms until it answers a truthy value or `ms` have passed. */
async function until(ms, probe, what, every) {
  const end = Date.now() + ms;
  for (;;) {
    const v = await probe();
    if (v) return v;
    if (Date.now() > end) fail(`not within ${ms} ms: ${what}`);
    await sleep(every || 50);
  }
}

async function rest(p, opts) {
  const r = await fetch(BASE + '/api/v1' + p, opts);
  return { status: r.status, headers: r.headers, json: r.headers.get('content-type')?.startsWith('application/json') ? await r.json() : await r.text() };
}

async function main() {
  check(BASE && TOKEN && SHOTS, 'GATEWAY_URL, PAGE_TOKEN and SCREENSHOT_DIR must be set');
  const origin = new URL(BASE).origin;
  const browser = await chromium.launch({ executablePath: CHROMIUM, headless: true, args: FLAGS });
  const context = await browser.newContext({ viewport: { width: 1366, height: 768 } });
  const urls = [];
  const outside = [];
  // Every request the page makes, recorded; one that would leave 127.0.0.1 is stopped.
  await context.route('**/*', (route) => {
    const url = route.request().url();
    urls.push(url);
    const u = new URL(url);
    if (u.protocol === 'data:' || u.hostname === '127.0.0.1') return route.continue();
    outside.push(url);
    return route.abort();
  });
  const page = await context.newPage();
  const consoleErrors = [];
  const expectedRefusals = [];
  page.on('console', (m) => {
    if (m.type() !== 'error') return;
    // The browser reports every 4xx answer in the console; the refusals this test provokes
    // (a write with a wrong token, a configuration with a mistake, an edit of an older version) are
    // expected.
    if (/Failed to load resource: the server responded with a status of (401|412|422)/.test(m.text())) expectedRefusals.push(m.text());
    else consoleErrors.push(m.text());
  });
  page.on('pageerror', (e) => consoleErrors.push(`uncaught: ${e.message}`));
  // Requests in flight at once (the SSE stream counts while open): within the listener's
  // per-client places (8 by default).
  let inFlight = 0; let maxInFlight = 0;
  page.on('request', () => { inFlight += 1; maxInFlight = Math.max(maxInFlight, inFlight); });
  page.on('requestfinished', () => { inFlight -= 1; });
  page.on('requestfailed', () => { inFlight -= 1; });

  // 1. The first look works without JavaScript: the server's snapshot names every line.
  {
    const plain = await browser.newContext({ javaScriptEnabled: false });
    const p = await plain.newPage();
    await p.goto(BASE + '/');
    const snap = await p.locator('#snapshot table.snap-lines tbody tr').count();
    check(snap === 5, `the snapshot without JavaScript shows ${snap} lines, not 5`);
    check(await p.locator('#snapshot').isVisible(), 'the snapshot is not visible without JavaScript');
    await plain.close();
    log('without JavaScript: the snapshot lists the 5 lines');
  }

  // 2. The five lines and the drive's tags.
  const t0 = Date.now();
  await page.goto(BASE + '/');
  await until(10000, async () => (await page.locator('#lines tbody tr').count()) === 5, 'five lines in the lines table');
  const names = await page.locator('#lines tbody tr th').allTextContents();
  check(JSON.stringify([...names].sort()) === JSON.stringify(['ascii', 'drive', 'hmi', 'ksvario', 'r3964']), `lines ${names}`);
  await until(10000, async () => (await page.locator('#tags tr[data-tag="drive/atv71/ULN"]').count()) === 1, "the drive's tag ULN");
  const driveTags = await page.locator('#tags details[data-dev="drive/atv71"] tbody tr th').allTextContents();
  for (const t of ['ETA', 'ULN', 'LFRD', 'ACC', 'SFr', 'HSP']) check(driveTags.includes(t), `drive tag ${t} missing from ${driveTags}`);
  log(`lines ${names.join(', ')} and ${driveTags.length} drive tags shown ${Date.now() - t0} ms after loading`);

  // 3. A value the simulator changes (the drive's mains voltage ULN wanders) is on screen
  //    within 2 s of the gateway reading it from the simulator.
  {
    const row = page.locator('#tags tr[data-tag="drive/atv71/ULN"]');
    const seen = [];
    let last = '';
    const end = Date.now() + 8000;
    while (Date.now() < end && seen.length < 4) {
      const [text, ts] = await row.evaluate((r) => [r.querySelector('td.value').textContent, r.getAttribute('data-ts')]).catch(() => ['', '']);
      if (text && text !== last) {
        if (last) seen.push({ text, lag: Date.now() - Date.parse(ts) });
        last = text;
      }
      await sleep(25);
    }
    check(seen.length >= 2, `ULN changed on screen ${seen.length} times in 8 s`);
    check(seen.every((s) => / V$/.test(s.text)), `ULN without its unit: ${seen.map((s) => s.text)}`);
    const worst = Math.max(...seen.map((s) => s.lag));
    check(worst <= 2000, `a ULN value appeared ${worst} ms after it was read`);
    const q = await row.locator('td.quality').textContent();
    check(/^good, \d+(\.\d)? s$/.test(q), `quality and age in words: ${q}`);
    log(`ULN changed ${seen.length} times on screen (${seen.map((s) => s.text).join(' → ')}), at most ${worst} ms after the gateway read it; quality "${q}"`);
  }

  // 4. The frame monitor shows a drive frame within 1 s.
  {
    await page.locator('#frames summary').click();
    await page.selectOption('#mon-line', 'drive');
    const fresh = await until(3000, () => page.evaluate(() => {
      const rows = [...document.querySelectorAll('#mon-rows tr')];
      const nowUs = Date.now() * 1000;
      const r = rows.reverse().find((x) => nowUs - Number(x.getAttribute('data-first-us')) < 1000000);
      return r ? { lag: (nowUs - Number(r.getAttribute('data-first-us'))) / 1000, text: r.textContent } : null;
    }), 'a drive frame less than 1 s old', 10);
    check(/slave [23] /.test(fresh.text), `not a drive frame: ${fresh.text}`);
    log(`frame monitor: a drive frame on screen ${fresh.lag.toFixed(0)} ms after its first byte: ${fresh.text.slice(0, 100)}`);
    // Keyboard: Enter on a frame opens its bytes in hex with ASCII, Escape closes it.
    await page.locator('#mon-rows tr:not([hidden])').last().focus();
    await page.keyboard.press('Enter');
    const dumpText = await page.locator('#mon-detail .dump').textContent();
    check(/^0000  [0-9a-f]{2}( [0-9a-f]{2})*/.test(dumpText), `hex dump: ${dumpText}`);
    await page.keyboard.press('Escape');
    check(await page.locator('#mon-detail').isHidden(), 'Escape did not close the frame detail');
    // Pause holds new frames back.
    await page.locator('body').press('p');
    const before = await page.locator('#mon-rows tr').count();
    await sleep(1200);
    const after = await page.locator('#mon-rows tr').count();
    check(before === after || after === 400, `paused, yet the list grew from ${before} to ${after}`);
    check(/paused: \d+ new frames? waiting/.test(await page.locator('#mon-state').textContent()), 'paused state not shown');
    await page.locator('body').press('p');
    log('frame monitor: keyboard detail (hex and ASCII), pause and resume work');
  }

  // 5. A tag write: without a token read-only and refused, with the token it reaches the drive.
  const acc = (await rest('/lines/drive/devices/atv71/tags/ACC')).json;
  const target = acc.value === 7.5 ? 6.5 : 7.5;
  const accRow = page.locator('#tags tr[data-tag="drive/atv71/ACC"]');
  {
    const auth = await page.locator('#auth').textContent();
    check(/read-only: changes need a token/.test(auth), `without a token the page says: ${auth}`);
    const why = await accRow.locator('button').getAttribute('title');
    check(/read-only/.test(why), `the disabled Write button does not say why: ${why}`);
    check(await accRow.locator('button').isDisabled(), 'the Write button is enabled without a token');
    // A token the gateway does not know: the server's refusal is shown.
    await page.fill('#token', 'not-the-token-of-this-gateway');
    await page.press('#token', 'Enter');
    await accRow.locator('input').fill(String(target));
    await accRow.locator('button').click();
    const refused = await until(15000, async () => {
      const t = await accRow.locator('.result').textContent().catch(() => '');
      return /^refused/.test(t) && t;
    }, 'the refusal of a wrong token on screen');
    check(/401/.test(refused), `refusal without the right token: ${refused}`);
    const still = (await rest('/lines/drive/devices/atv71/tags/ACC')).json;
    check(still.value === acc.value, `ACC changed to ${still.value} by a refused write`);
    log(`without a token: read-only ("${auth}"); with a wrong one the write shows "${refused}"`);
  }
  {
    await page.locator('#token-forget').click();
    await page.fill('#token', TOKEN);
    await page.press('#token', 'Enter');
    check(/token set/.test(await page.locator('#auth').textContent()), 'token not taken');
    const stored = await page.evaluate(() => Object.keys(sessionStorage).length);
    check(stored === 1, 'the token is not kept in sessionStorage');
    await accRow.locator('input').fill(String(target));
    await accRow.locator('button').click();
    const ok = await until(15000, async () => {
      const t = await accRow.locator('.result').textContent().catch(() => '');
      return /^written/.test(t) && t;
    }, 'the write confirmed on screen');
    const wrote = Date.now();
    // The drive's own value: read by the next poll of the simulator after the write.
    const polled = await until(15000, async () => {
      const t = (await rest('/lines/drive/devices/atv71/tags/ACC')).json;
      return t.value === target && Date.parse(t.timestamp) > wrote + 500 && t;
    }, `ACC = ${target} read back from the simulator by a later poll`, 250);
    log(`with the token: "${ok}"; the simulator answers ACC = ${polled.value} ${polled.unit} at the poll of ${polled.timestamp}`);
    await rest('/lines/drive/devices/atv71/tags/ACC', { method: 'PUT', headers: { Authorization: `Bearer ${TOKEN}`, 'Content-Type': 'application/json' }, body: JSON.stringify({ value: acc.value }) });
  }

  // 6. A configuration edit with a mistake: the error at its path, nothing changed.
  {
    const before = await rest('/config');
    const etag = before.headers.get('etag');
    const started = (await rest('/lines/drive')).json.started;
    await page.locator('#config summary').click();
    await until(15000, async () => (await page.inputValue('#cfg-text')).includes('[lines.'), 'the configuration loaded');
    await page.selectOption('#cfg-scope', 'drive');
    const text = await page.inputValue('#cfg-text');
    check(/^\[lines\.drive\]/.test(text) && !text.includes('[lines.ksvario]'), `the drive's part: ${text.slice(0, 200)}`);
    await page.fill('#cfg-text', text.replace(/parity = "even"/, 'parity = "sometimes"'));
    await page.locator('#cfg-validate').click();
    const issue = await until(15000, async () => {
      const t = await page.locator('#cfg-issues').textContent();
      return t.includes('lines.drive.parity') && t;
    }, 'the problem at lines.drive.parity').catch(async (e) => {
      fail(`${e.message}; the page says "${await page.locator('#cfg-state').textContent()}", issues "${await page.locator('#cfg-issues').textContent()}"`);
    });
    check(await page.locator('#cfg-apply').isDisabled(), 'Apply is possible after a failed validation');
    check(/nothing changed/.test(await page.locator('#cfg-state').textContent()), 'the page does not say that nothing changed');
    await page.locator('#cfg-issues button').first().click();
    const selected = await page.evaluate(() => { const t = document.getElementById('cfg-text'); return t.value.slice(t.selectionStart, t.selectionEnd); });
    check(/parity/.test(selected), `the path's button selects "${selected}"`);
    const after = await rest('/config');
    check(after.headers.get('etag') === etag, 'the configuration changed');
    check((await rest('/lines/drive')).json.started === started, 'the drive line was restarted');
    log(`configuration: "${issue.trim()}" shown, Apply disabled, the ETag ${etag} and the line unchanged`);
  }

  // 6b. A valid one-line edit, applied with If-Match: refused (412) when the configuration changed
  //     since the page loaded it, applied after loading it again; only that line restarts.
  {
    const ascii = (await rest('/lines/ascii')).json.started;
    await page.selectOption('#cfg-scope', 'r3964');
    const edit = async () => {
      const t = await page.inputValue('#cfg-text');
      check(/^\[lines\.r3964\]/.test(t) && /baud = 9600/.test(t), `the r3964 part: ${t.slice(0, 200)}`);
      await page.fill('#cfg-text', t.replace('baud = 9600', 'baud = 19200'));
      await page.locator('#cfg-validate').click();
      await until(15000, () => page.locator('#cfg-apply').isEnabled(), 'Apply after a valid validation');
    };
    await edit();
    // Someone else changes the configuration meanwhile (a key that only a restart applies).
    const toml = (await rest('/config', { headers: { Accept: 'application/toml' } })).json;
    const other = await rest('/config', { method: 'PUT', headers: { Authorization: `Bearer ${TOKEN}`, 'Content-Type': 'application/toml' }, body: toml.replace('[http]\n', '[http]\nbody_limit = 2097152\n') });
    check(other.status === 200, `the other change: ${other.status} ${JSON.stringify(other.json)}`);
    await page.locator('#cfg-apply').click();
    const stale = await until(15000, async () => {
      const t = await page.locator('#cfg-state').textContent();
      return /changed since it was loaded/.test(t) && t;
    }, 'the refusal of an edit of an older version');
    check((await rest('/config/lines/r3964')).json.baud === 9600, 'the refused edit changed r3964');
    await page.locator('#cfg-load').click();
    await until(15000, async () => (await page.inputValue('#cfg-text')).includes('baud = 9600'), 'the newer version loaded');
    await edit();
    await page.locator('#cfg-apply').click();
    const applied = await until(30000, async () => {
      const t = await page.locator('#cfg-state').textContent();
      return /^applied/.test(t) && t;
    }, 'the edit applied');
    check(/lines restarted: r3964/.test(applied), `applied: ${applied}`);
    const after = (await rest('/config')).json;
    check(after.lines.r3964.baud === 19200 && after.http.body_limit === 2097152, `after the edit: r3964 ${after.lines.r3964.baud}, body_limit ${after.http.body_limit}`);
    check((await rest('/lines/ascii')).json.started === ascii, 'another line was restarted');
    log(`configuration: an edit of an older version is refused ("${stale}"); after Load: "${applied}", the other change kept`);
  }

  // 7. Phone width: nothing wider than the screen but the tables' own scroll boxes.
  {
    await page.setViewportSize({ width: 390, height: 844 });
    await sleep(300);
    const width = await page.evaluate(() => document.documentElement.scrollWidth);
    check(width <= 391, `at 390 px the page is ${width} px wide`);
    await page.setViewportSize({ width: 1366, height: 768 });
    log(`phone width 390 px: the page is ${width} px wide`);
  }

  // 8. The screenshot (CI artifact; with README_SCREENSHOT also the README's picture).
  {
    await page.locator('#frames summary').click();
    await page.locator('#config summary').click();
    await page.evaluate(() => window.scrollTo(0, 0));
    await sleep(1200);
    fs.mkdirSync(SHOTS, { recursive: true });
    const file = path.join(SHOTS, 'status-page.png');
    await page.screenshot({ path: file });
    await page.screenshot({ path: path.join(SHOTS, 'status-page-full.png'), fullPage: true });
    if (README_SHOT) fs.copyFileSync(file, README_SHOT);
    log(`screenshot ${file}`);
  }

  // 9. Every request stayed on 127.0.0.1, no script error, within the client's places.
  check(outside.length === 0, `requests that would leave 127.0.0.1: ${outside.join(', ')}`);
  check(urls.every((u) => u.startsWith(origin + '/') || u.startsWith('data:')), `requests elsewhere: ${urls.filter((u) => !u.startsWith(origin))}`);
  check(consoleErrors.length === 0, `console errors: ${consoleErrors.join(' | ')}`);
  check(maxInFlight <= 4, `${maxInFlight} requests at once`);
  const paths = [...new Set(urls.map((u) => new URL(u).pathname.replace(/\/lines\/[^/]+/, '/lines/*').replace(/\/tags\/.*/, '/tags/*')))].sort();
  log(`${urls.length} requests, all to ${origin}, at most ${maxInFlight} at once; paths: ${paths.join(' ')}`);
  log(`console: no script error (${expectedRefusals.length} expected refusals reported by the browser)`);
  await browser.close();
}

main().then(() => { log('all checks passed'); }, (e) => { console.error(`page-test: FAILED: ${e.message}`); process.exit(1); });
