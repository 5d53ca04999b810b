"""Tests of aectorch.evaluation."""
