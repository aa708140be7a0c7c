"""Tests of the bench runner and its benches."""
