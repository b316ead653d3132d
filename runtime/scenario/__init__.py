"""``softplc test``: scenarios (a simulation script with expectations) run on the virtual
clock, their failures as one line each, SFC coverage, JUnit XML (docs/testing-charts.md)."""
