"""Tests of aectorch.framework."""
