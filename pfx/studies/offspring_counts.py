r"""Offspring counts of the resamplers: is :math:`E[N_j] = N w_j`?

For fixed normalised weights :math:`w_1..w_N`, each resampler is run ``draws`` times and the
offspring count :math:`N_j` of every particle is averaged. An unbiased scheme has
:math:`E[N_j] = N w_j`; han-lee's Algorithm IV as printed (the N smallest of N + 1 sorted
uniforms) has :math:`E[N_j] = (N+1) w_j - (C_j^{N+1} - C_{j-1}^{N+1})` instead
(:func:`pfx.filters.particle.resampling.han_lee_iv_expected_counts`; docs/reference-facts.md#resampling). The default weights
are the worked example there, w = (.3, .1, .2, .15, .25), whose Algorithm IV expectation is
(1.799, 0.597, 1.157, 0.769, 0.678) instead of (1.5, 0.5, 1, 0.75, 1.25).

Table ``offspring``: one row per (resampler, particle) with the weight, the unbiased target
``target_count`` = N w, the scheme's own theoretical expectation ``expected_count``, the
observed mean count ``observed_mean`` and its standard error ``observed_sem`` over the draws,
and ``z_score`` = (observed - target) / sem.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import pandas as pd
from pydantic import Field, StrictFloat, StrictInt, field_validator

from pfx.filters.particle.resampling import RESAMPLERS, han_lee_iv_expected_counts, offspring_counts
from pfx.numerics.seeding import TrialStreams
from pfx.studies.base import STUDIES, Study

ResamplerName = Literal[RESAMPLERS.names()]  # type: ignore[valid-type]


@STUDIES.register_kind
class OffspringCounts(Study):
    """Mean offspring count per particle for each resampler, against N w (bias check)."""

    kind: Literal["offspring_counts"] = "offspring_counts"
    weights: list[StrictFloat] = Field([0.3, 0.1, 0.2, 0.15, 0.25], min_length=2, max_length=10_000,
                                       description="normalised weights w_1..w_N (non-negative, sum 1)")
    draws: StrictInt = Field(100_000, ge=10, le=10_000_000, description="resampling repetitions")
    resamplers: list[ResamplerName] = Field(  # type: ignore[valid-type]
        default_factory=lambda: list(RESAMPLERS.names()), min_length=1,
        description="resamplers to compare (`pfx list resamplers`)")

    @field_validator("weights")
    @classmethod
    def _normalised(cls, weights: list[float]) -> list[float]:
        if min(weights) < 0 or abs(sum(weights) - 1.0) > 1e-9:
            raise ValueError("weights must be non-negative and sum to 1")
        return weights

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        weights = np.asarray(self.weights)
        n = weights.size
        rows = []
        for name in self.resamplers:
            resampler = RESAMPLERS[name]
            # One generator, used for every repetition in turn (each row draws after the last).
            streams = TrialStreams([random] * self.draws)
            counts = offspring_counts(resampler(np.broadcast_to(weights, (self.draws, n)), streams), n)
            mean = counts.mean(axis=0)
            sem = counts.std(axis=0, ddof=1) / np.sqrt(self.draws)
            expected = n * weights if resampler.unbiased else han_lee_iv_expected_counts(weights)
            for j in range(n):
                z = (mean[j] - n * weights[j]) / sem[j] if sem[j] > 0 else 0.0
                rows.append({"resampler": name, "unbiased": resampler.unbiased, "particle": j + 1,
                             "weight": weights[j], "target_count": n * weights[j],
                             "expected_count": expected[j], "observed_mean": mean[j],
                             "observed_sem": sem[j], "z_score": z, "draws": self.draws})
        return {"offspring": pd.DataFrame(rows)}
