"""Tests of aectorch.report."""
