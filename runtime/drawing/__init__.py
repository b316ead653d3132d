"""Drawing: a chart in IEC 60848 style and a trace as a chronogram, as SVG."""
