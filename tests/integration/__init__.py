"""Tests that cross packages: both systems' warps and the shared loop, and every console script's error policy."""
