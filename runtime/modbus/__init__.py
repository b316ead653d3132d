"""The plant's Modbus/TCP server (``softplc modbus``, its own process, docs/modbus.md)."""
