// The status page, live. Every request goes to the REST API of this same gateway (/api/v1):
// polls one at a time at most once a second, the frame monitor as one Server-Sent Events
// stream, changes with the token the user pasted (kept in this tab's sessionStorage only).
//
// The script is ES modules, one per part of the page, served by the gateway from its binary
// (no build step). This entry asks for them one after the other, lowest first: each module's
// own imports are then already in the browser's module map, so loading the page holds at most
// one request for a script at a time (a browser would otherwise open up to six connections for
// them at once, of the client's `max_connections_per_client` places).
//
//   base       constants, the page's state, elements, words for times and STATUS words, the URL
//   rest       requests to /api/v1, the token, the write paths in words
//   poll       the polls of status, tags, diagnostics, mailboxes and the fleet
//   overview   the header, problems, fleet, lines and devices
//   tags       the tag tables, trends and writes
//   mailboxes  the telegram mailboxes and the diagnostic buffers
//   monitor    the frame monitor
//   config     the configuration editor
//   main       the token field, the round of polls, rendering every section, the start
document.documentElement.classList.add('js');

const MODULES = ['base', 'rest', 'poll', 'overview', 'tags', 'mailboxes', 'monitor', 'config', 'main'];
for (const name of MODULES) await import(`./${name}.js`);
