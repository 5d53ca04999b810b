"""Whole runs checked end to end: a default run against the recorded fixture, a study's commands,
and damaged run files read by the commands."""
