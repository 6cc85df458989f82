"""Precomputed tables (tables.npz) and the script that builds them (build_tables)."""
