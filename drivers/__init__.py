"""softplc I/O drivers: one module per back-end, all built on drivers.base.Driver."""
