"""Self-contained HTML verification reports (figures embedded as base64 PNG).

The report reads stored results only (``runs/*/`` Parquet + ``run.json`` and
``verdict.json``); it never reruns a simulation.
"""
