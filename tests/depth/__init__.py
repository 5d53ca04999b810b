"""Tests of aectorch.depth."""
