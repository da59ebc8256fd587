"""The real-data benchmarks' score tables and verdicts (pfx/papers/score_tables.py), on a small
run of the Nile's local level: the Kalman filter's exact scores against the particle filter's,
and a particle filter that assumes the wrong measurement variance, which must be told apart."""

from __future__ import annotations

import pytest
from conftest import REPO_ROOT

import pfx
from pfx.papers.base import PaperResults
from pfx.papers.score_tables import score_part

pytestmark = pytest.mark.usefixtures("fresh_plugins")

CONFIG = """
name: scores
seed: 1871
trials: 30
model:
  kind: linear_gaussian
  transition_matrix: [[1.0]]
  measurement_matrix: [[1.0]]
  names: [level]
  process_noise: {{variance: 1469.1}}
  measurement_noise: {{variance: 15099.0}}
  initial: {{kind: gaussian, mean: [0.0], covariance: 1.0e7}}
data:
  measurements: {data}
filter: {{particles: 1000, resampler: systematic, ess_threshold: 0.5}}
arms:
  KF: {{kind: kf}}
  PF: {{}}
  PF-wrong: {{model: {{measurement_noise: {{variance: 2000.0}}}}}}
metrics: {{scores: true}}
outputs: {{trace_trials: 1, figures: [pit_histogram]}}
"""


def test_score_part_tells_the_exact_scores_from_a_wrong_model(tmp_path):
    config = tmp_path / "scores.yaml"
    config.write_text(CONFIG.format(data=REPO_ROOT / "examples" / "data" / "nile.csv"))
    paper = tmp_path / "estimation-nile"
    pfx.run(config, out=paper / "scores")
    items, verdicts = score_part(PaperResults(paper), "scores", by="arm", baseline="KF", claim="agree")
    table = items[0].markdown
    assert "PF-wrong" in table and "(baseline)" in table and "KS p" in table
    assert any(getattr(item, "name", "") == "pit_histogram.png" for item in items[1:])
    # the right particle filter agrees with the exact scores; the wrong model does not
    assert verdicts[0].verdict == "partly reproduced", verdicts[0].evidence
    evidence = verdicts[0].evidence
    assert "PF crps_z1" in evidence and "PF-wrong crps_z1" in evidence
    assert score_part(PaperResults(paper), "missing", by="arm", baseline="KF", claim="x") == ((), ())
