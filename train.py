"""aectorch training entry point (Hydra).

This is a demonstration until the joint learning framework (simulated HOAP-3 head,
natural actor-critic eye control, depth MLP) lands: it learns binocular sparse-coding
dictionaries (coarse and fine scale) from synthetic stereo pairs with random disparities
and writes a figure, metrics, TensorBoard logs and the trained encoder to Hydra's run folder.

    python train.py                                   # defaults (aectorch.config.DemoConfig)
    python train.py steps=50 seed=3 hydra.run.dir=/tmp/x
    python train.py -m seed=0,1,2                     # multirun sweep

Invalid values exit with status 2 and one ``error: ...`` line; set ``AECTORCH_DEBUG=1``
for the full traceback.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from aectorch.config import DemoConfig, register_configs
from aectorch.demo import run_demo

register_configs()


def _debug() -> bool:
    return os.environ.get("AECTORCH_DEBUG", "") not in ("", "0")


def _fail(message: str) -> None:
    print(f"error: {message} (AECTORCH_DEBUG=1 for the traceback)", file=sys.stderr)
    sys.exit(2)


@hydra.main(version_base=None, config_name="train")
def main(raw: DictConfig) -> dict:
    try:
        cfg: DemoConfig = OmegaConf.to_object(raw)
    except ValueError as err:  # a value rejected by DemoConfig.__post_init__
        if _debug():
            raise
        # Exit here, inside the job: Hydra would add its own "Error executing job" line.
        _fail(str(err))
    torch.set_num_threads(cfg.threads)
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(raw, resolve=True))
    return run_demo(cfg, run_dir)


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    cause = err.__cause__
    if isinstance(err, HydraException) and isinstance(cause, OmegaConfBaseException):
        # e.g. "Error merging override steps=abc: Value 'abc' ... could not be converted to Integer"
        text = f"{text}: {str(cause).strip().splitlines()[0]}"
    return text


if __name__ == "__main__":
    # Let Hydra re-raise instead of printing and exiting 1, so config errors can be reported here.
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        main()
    except (HydraException, OmegaConfBaseException) as err:  # bad override: type, unknown key
        if _debug():
            raise
        _fail(_one_line(err))
