"""Deterministic qualitative relational mapping with camera measurements (M, MT; SPEC §4)."""
