"""Tests of aectorch.sim."""
