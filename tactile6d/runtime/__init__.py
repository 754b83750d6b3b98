"""How work runs: the executor that spreads work over processes (``executor``), the pin that gives the same
bits on every CPU (``instruction_sets``), and what every pipeline stage shares (``stage_args``: its command
line; ``stage_clock``: its timings).

Layer 3 of 8: imports ``core`` and ``data``.
"""
