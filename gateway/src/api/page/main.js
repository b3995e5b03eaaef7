// The page's start: the token field, the round of polls and the rendering of every section.
import { POLL_MS, TOKEN_KEY, S, $, sleep, restoreOpen, rememberOpen } from './base.js';
import { showAuth, loadConfigFacts } from './rest.js';
import { pollStatus, pollTags, pollDiag, pollTelegrams, findFleet, pollFleet } from './poll.js';
import { renderHeader, renderProblems, renderFleet, renderLines, renderDevices } from './overview.js';
import { renderTags } from './tags.js';
import { renderMailboxes, renderDiag } from './mailboxes.js';
import { fillLineSelects, monitorStart, monitorStop } from './monitor.js';
import { cfgLoad } from './config.js';

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

// --- the token ---------------------------------------------------------------------------

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
