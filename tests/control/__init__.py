"""Tests of aectorch.control."""
