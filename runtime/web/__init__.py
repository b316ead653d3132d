"""``softplc web``: the live view of a running plant in the browser (docs/web.md)."""
