"""Controller: the real-time daemon, its scheduler, statistics, retain, logging,
systemd notification and service installation."""
