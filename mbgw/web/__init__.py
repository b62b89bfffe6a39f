"""The web console, served by the daemon itself on its asyncio loop (aiohttp): `hooks` (what
a daemon hands it: its control commands, trace hub, file, reload), `console` (the daemon's
handle: aiohttp imported only when [web] listen is on), `server`
(`start_web`: the site, started, restarted on a reload that changes [web], closed at stop),
`api` (the JSON API under /api: status, clients, devices, scenarios, table, stats, trace,
config), `auth` (logins, sessions, CSRF tokens, the login rate limit), `passwords` (the
scrypt hashes `mbgw config password` writes), `config_api` (the configuration file read,
edited and uploaded with the same checks as `mbgw config set` and check-config), `static/`
(the pages: one page app, index.html, console.js, pcap.js, console.css; every value set as
text).  It reads through the same hooks as the control socket (the daemon hands it its
control commands and trace hub) and is never on the line thread's path."""
