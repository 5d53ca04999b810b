"""Tests of aectorch.ops."""
