// The status page's fleet section in Debian's Chromium (playwright-core, pinned in package.json):
// the page of one gateway lists the other gateways of the zenoh fabric, each online, with a link
// to its own page. Started by tests/tests/fleet.rs with three gateways behind one router:
//
//   GATEWAY_URL=http://127.0.0.1:PORT FLEET='g2=http://127.0.0.1:P2,g3=http://127.0.0.1:P3' \
//     node fleet-test.js
//
// Prints one line per check; exits 1 with the reason at the first check that fails.
'use strict';

const { chromium } = require('playwright-core');

const BASE = process.env.GATEWAY_URL;
const FLEET = process.env.FLEET;
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--no-first-run'];

function fail(msg) { throw new Error(msg); }
function check(ok, msg) { if (!ok) fail(msg); }
const log = (what) => console.log(`fleet-test: ${what}`);

async function main() {
  check(BASE && FLEET, 'GATEWAY_URL and FLEET must be set');
  // The others, by name, and the page each one's link must open.
  const expected = FLEET.split(',').map((pair) => pair.split('='));
  const browser = await chromium.launch({ executablePath: CHROMIUM, headless: true, args: FLAGS });
  const context = await browser.newContext({ viewport: { width: 1366, height: 768 } });
  const outside = [];
  await context.route('**/*', (route) => {
    const u = new URL(route.request().url());
    if (u.protocol === 'data:' || u.hostname === '127.0.0.1') return route.continue();
    outside.push(u.href);
    return route.abort();
  });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  const t0 = Date.now();
  await page.goto(BASE + '/');
  // The section appears once the page has asked GET /api/v1/fleet (at its first round).
  await page.waitForFunction((names) => {
    const section = document.getElementById('fleet');
    if (!section || section.hidden) return false;
    const rows = [...section.querySelectorAll('tbody tr')];
    return names.every((n) => rows.some((r) => r.querySelector('th')?.textContent === n
      && /online/.test(r.textContent)));
  }, expected.map(([name]) => name), { timeout: 30000 });
  const rows = await page.$$eval('#fleet tbody tr', (rs) => rs.map((r) => ({
    name: r.querySelector('th').textContent,
    text: r.textContent,
    href: r.querySelector('a')?.getAttribute('href') || '',
  })));
  log(`fleet section after ${Date.now() - t0} ms: ${JSON.stringify(rows)}`);
  check(rows.length === expected.length, `${rows.length} rows, expected ${expected.length}`);
  for (const [name, link] of expected) {
    const row = rows.find((r) => r.name === name);
    check(row, `no row for ${name}`);
    check(row.href.replace(/\/$/, '') === link, `${name} links to '${row.href}', expected ${link}`);
  }
  // The section opens as a user opens it (its summary), and the link opens the other gateway's
  // own page.
  const [name, link] = expected[0];
  await page.click('#fleet summary');
  await page.click(`#fleet a[href^="${link}"]`);
  await page.waitForFunction((n) => document.body.textContent.includes(n), name, { timeout: 10000 });
  check(page.url().startsWith(link), `the link opened ${page.url()}`);
  log(`the link of ${name} opened ${page.url()}`);
  check(outside.length === 0, `requests left 127.0.0.1: ${outside.join(' ')}`);
  check(errors.length === 0, `script errors: ${errors.join(' | ')}`);
  await browser.close();
  log('all checks passed');
}

main().catch((e) => {
  console.error(`fleet-test: FAILED: ${e.message}`);
  process.exit(1);
});
