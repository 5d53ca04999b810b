"""Tests of aectorch.visualize."""
