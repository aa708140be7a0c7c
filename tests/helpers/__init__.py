"""Helpers that several test packages share (plain functions; fixtures live in conftest.py)."""
