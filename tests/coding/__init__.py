"""Tests of aectorch.coding."""
