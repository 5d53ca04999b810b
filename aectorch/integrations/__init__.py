"""Optional bridges to other projects, each imported lazily with its own extra.

- `aectorch.integrations.lerobot` (extra ``aectorch[lerobot]``): record aectorch trials as a
  LeRobotDataset, and feed `BinocularEncoder` from any LeRobotDataset with two camera streams.
"""
