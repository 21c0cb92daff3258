"""`wild-thermal-demo` with the random generators seeded as `ns-train` seeds them, for any version of
the package (run as a script with that version first on PYTHONPATH): versions from before
`training.trainer.seeded_trainer` built the demo's model unseeded, so two of their runs never matched.

    PYTHONPATH=TREE python experiments/seeded_demo.py --output-dir OUT
"""

import random

import numpy as np
import torch
from nerfstudio.engine.trainer import TrainerConfig

from thermal_wild_ns.demo import entrypoint

_setup = TrainerConfig.setup


def _seeded_setup(self, **kwargs):
    """Seed right before the trainer is built, where `seeded_trainer` (and ns-train) seed."""
    random.seed(self.machine.seed)
    np.random.seed(self.machine.seed)
    torch.manual_seed(self.machine.seed)
    return _setup(self, **kwargs)


if __name__ == "__main__":
    TrainerConfig.setup = _seeded_setup
    entrypoint()
