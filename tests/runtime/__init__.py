"""Tests of aectorch.runtime."""
