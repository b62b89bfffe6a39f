"""The network pieces every listener and connection shares, whatever the mode: listening
sockets (listen), addresses (address), authip (acl), TLS (tls) and the logs kept to once a
minute (ratelimit).  Imports errors, audit and config only."""
