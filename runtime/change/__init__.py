"""Online change: what an edit changes (``diff``), and loading it into a running plant
between two scans with its state carried over (``plan``: ``prepare`` then ``apply``)."""
