"""The renderers of `scripts/render_docs.py`, one module per kind of table."""
