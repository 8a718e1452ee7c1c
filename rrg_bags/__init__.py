"""Bags: the MCAP bag recorder node, the writer, and ``rrg-bag`` (info, plot, summary,
replay, finalize)."""
