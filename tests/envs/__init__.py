"""Tests of aectorch.envs."""
