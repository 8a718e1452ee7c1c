"""Bringing RRG up: the launcher (``rrg-launch``), its process supervisor, the soak, and
every benchmark (``rrg-bench``)."""
