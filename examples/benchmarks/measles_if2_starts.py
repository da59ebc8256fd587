"""Draw the starting points of the measles-london IF2 search (configs/benchmarks/measles-london/if2.yaml).

He et al. (2010) estimated their model for twenty towns of England and Wales; their estimates
(Table 2 of the paper, as pomp's lessons and pypomp 1.1.0's ``AK_mles.csv`` carry them) span the
box below: for each of the ten parameters estimated besides the initial fractions, the smallest
and the largest of the twenty towns' values. London's own estimate lies at an edge of the box in
five of them (R0, sigma, gamma, iota and amplitude), so a search from points scattered over the
box starts far from it.

The search's eight replicates start at points drawn uniformly over the box (pomp's
``runif_design``), from NumPy's PCG64 with seed 2010. Run it from the repository's root; it
prints the ``start`` lists pasted into if2.yaml, rounded to three significant digits:

    python examples/benchmarks/measles_if2_starts.py
"""

from __future__ import annotations

import numpy as np

REPLICATES = 8
SEED = 2010

# (smallest, largest) over the twenty towns' maximum-likelihood estimates, natural scale.
TWENTY_TOWNS_BOX = {
    "R0": (21.4, 56.8),
    "sigma": (28.9, 73.6),
    "gamma": (30.4, 301.0),
    "iota": (0.00912, 2.9),
    "rho": (0.131, 0.795),
    "sigmaSE": (0.038, 0.0955),
    "psi": (0.116, 2.87),
    "cohort": (0.191, 0.648),
    "amplitude": (0.153, 0.554),
    "alpha": (0.937, 1.04),
}


def starting_points(replicates: int = REPLICATES, seed: int = SEED) -> dict[str, list[float]]:
    """Each parameter's starts, one per replicate, uniform over the box, three significant digits."""
    generator = np.random.default_rng(seed)
    return {name: [float(f"{value:.3g}") for value in generator.uniform(low, high, size=replicates)]
            for name, (low, high) in TWENTY_TOWNS_BOX.items()}


def main() -> None:
    for name, starts in starting_points().items():
        print(f"{name}: [{', '.join(f'{value:g}' for value in starts)}]")


if __name__ == "__main__":
    main()
