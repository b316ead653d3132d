"""PLCopen TC6 XML v2.01 (IEC 61131-10): SFC charts imported from and exported to the editors'
exchange format (``softplc import``, ``softplc export``; docs/plcopen.md)."""
