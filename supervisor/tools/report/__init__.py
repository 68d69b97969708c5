"""``safety-supervisor report``: one self-contained HTML page about violation logs.

Integrity of the hash chain, a zoomable timeline of the inputs with every record marked
on it, per requirement counts, mitigation outcomes and latencies, and for each violation
the formula's subformulas at the violating tick (docs/reference/commands.md, "report").
"""
