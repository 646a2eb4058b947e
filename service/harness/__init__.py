"""The evaluation harness: the paper's experiments, reproducibly, against the baselines users
would pick instead (``gridplace bench paper``).

>>> from service.harness import BenchConfig, load_dataset, run_paper
>>> run_paper(load_dataset("../shared/data/nordland-64x32"), Path("results"), BenchConfig.quick())
"""

from service.harness.config import EXPERIMENTS, BenchConfig
from service.harness.datasets import Dataset, load_dataset, synthetic_dataset
from service.harness.powerlaw import PowerLawFit, fit_power_law
from service.harness.runner import run_paper

__all__ = [
    "EXPERIMENTS",
    "BenchConfig",
    "Dataset",
    "PowerLawFit",
    "fit_power_law",
    "load_dataset",
    "run_paper",
    "synthetic_dataset",
]
