"""Console: the line protocol, sessions and commands, the socket/serial server, the PIN,
and the curses monitor client."""
