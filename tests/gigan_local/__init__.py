"""Tests of gigan_local (the GIGAN client)."""
