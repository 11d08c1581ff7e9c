"""The benchmark: `python -m global_loc.bench [--quick]` (see README)."""
