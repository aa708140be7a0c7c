"""Tests of baseline_cloudbaking (server, GI tree, codecs, client)."""
