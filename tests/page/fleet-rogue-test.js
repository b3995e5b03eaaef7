// The status page's fleet section in Debian's Chromium (playwright-core, pinned in package.json)
// while a rogue zenoh peer fills the fleet with members whose HTTP address is 28 KiB of text
// (`http://x/AAAA...`): the section lists at most 256 of them, every address as text and none as
// a link. Started by tests/tests/fleet_rogue.rs:
//
//   GATEWAY_URL=http://127.0.0.1:PORT node fleet-rogue-test.js
//
// Prints one line per check; exits 1 with the reason at the first check that fails.
'use strict';

const { chromium } = require('playwright-core');

const BASE = process.env.GATEWAY_URL;
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--no-first-run'];

function check(ok, msg) { if (!ok) throw new Error(msg); }
const log = (what) => console.log(`fleet-rogue-test: ${what}`);

async function main() {
  check(BASE, 'GATEWAY_URL must be set');
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
  await page.goto(BASE + '/');
  await page.waitForFunction(() => {
    const section = document.getElementById('fleet');
    return section && !section.hidden && section.querySelectorAll('tbody tr').length > 0;
  }, null, { timeout: 30000 });
  const seen = await page.$$eval('#fleet tbody tr', (rs) => ({
    rows: rs.length,
    links: rs.filter((r) => r.querySelector('a')).length,
    asText: rs.filter((r) => /http:\/\/x\/A/.test(r.textContent)).length,
    longest: Math.max(...rs.map((r) => r.textContent.length)),
  }));
  log(`fleet section: ${JSON.stringify(seen)}`);
  check(seen.rows <= 256, `${seen.rows} rows`);
  check(seen.links === 0, `${seen.links} rows offer a rogue's address as a link`);
  check(seen.asText === seen.rows, `${seen.asText} of ${seen.rows} rows show the address as text`);
  check(seen.longest < 2048, `a row of ${seen.longest} characters`);
  check(outside.length === 0, `requests left 127.0.0.1: ${outside.join(' ')}`);
  check(errors.length === 0, `script errors: ${errors.join(' | ')}`);
  await browser.close();
  log('all checks passed');
}

main().catch((e) => {
  console.error(`fleet-rogue-test: FAILED: ${e.message}`);
  process.exit(1);
});
