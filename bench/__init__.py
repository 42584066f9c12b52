"""
Benchmarks of ext_observer: ``python -m bench`` (``make bench``).

Prints one set of Markdown tables and writes it to ``docs/performance.md``:
batch speed of the core and its ceilings, node throughput and latency
against a bare relay on each executor, accuracy beside the physical limit,
and where the node's per-message time goes. Benchmarks print figures and
never fail on timing.
"""
