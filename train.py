"""The training command, `aectorch.cli.train` (also the console script ``aectorch-train``); see its docstring."""
import os
import sys

# Idle OpenMP threads sleep instead of spinning: with a spinning thread, loops of small ops on 2 threads ran
# 15-45x slower while another process held a core (docs/performance.md). Set before torch loads OpenMP.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from aectorch.cli.train import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
