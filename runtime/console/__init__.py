"""Console: the line protocol, the service every session shares, sessions, commands,
streams, the socket/serial server, the PIN, and the curses monitor client."""
