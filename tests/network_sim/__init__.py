"""Tests of network_sim."""
