"""Tests of gicore."""
