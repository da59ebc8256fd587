"""``pfx bench``: it runs, prints every row, and every implementation does the same work.

No timing is asserted anywhere (speed is what the benchmark reports, as ratios). What is
tested: the command in ``--quick`` mode prints the machine line, a row per case and
implementation, the memory and workers lines and the targets; the benchmark's NumPy model is
pfx's model; the reference filter (and each peer library that is installed) estimates the
altitude as well as pfx does, trial by trial, within a tolerance from the standard error.
"""

from __future__ import annotations

from itertools import takewhile

import numpy as np
import pytest

from pfx.bench import QUICK_CASES
from pfx.bench.peers import ADAPTERS, PEERS
from pfx.bench.problem import FallingBodyProblem, make_case
from pfx.bench.timing import run_numpy, run_pfx

Z = 4.5        # two-sided P(|Z| > 4.5) = 7e-6 per comparison


@pytest.fixture(scope="module")
def quick_output(run_pfx):
    result = run_pfx("bench", "--quick", "--repeats", "1", timeout=600)
    assert result.returncode == 0, result.output
    return result.stdout


def test_quick_bench_prints_every_row(quick_output):
    lines = quick_output.splitlines()
    assert lines[0].startswith("pfx bench: falling body")
    assert any(line.startswith("machine: ") and "numpy" in line and "cores" in line for line in lines)
    assert any(line.startswith("numba: compiled loops ready in") for line in lines)
    header = next(i for i, line in enumerate(lines) if line.startswith("case ") and "ns/particle-step" in line)
    table = lines[header + 2:lines.index("", header)]
    rows, label = {}, None
    for line in table:
        label = line[:16].strip() or label
        name, *numbers = line[16:].split()
        rows.setdefault(label, []).append(name)
        if numbers[0] != "failed:":     # ns/particle-step, ratio to pfx, RMSE, runs
            float(numbers[0]), float(numbers[1]), float(numbers[2]), int(numbers[3])
    labels = [f"N={n}" if trials == 1 else f"{trials} x N={n}" for n, trials in QUICK_CASES]
    assert list(rows) == labels
    for label in labels:
        assert rows[label][:2] == ["pfx", "numpy"], (label, rows[label])
    assert any(line.startswith("memory, N=10000, 1 trial:") and "bytes per particle" in line for line in lines)
    assert any(line.startswith("workers, sweep of 8 cells") and "speed-up" in line for line in lines)
    goals = lines.index("goals (ratios of best wall times on this machine):")
    goal_lines = list(takewhile(lambda line: line.startswith("  "), lines[goals + 1:]))
    assert len(goal_lines) == 7, goal_lines
    assert goal_lines[0].startswith("  N=1e3, 1 trial: pfx time / numpy reference time: goal ")


def test_bench_model_is_pfx_model():
    """The NumPy functions the reference and the peers use are pfx's falling body (Euler, dt 0.1)."""
    case = make_case(50, 1)
    model = case.cell.filter_model
    problem = FallingBodyProblem.from_cell(case.cell)
    x = problem.sample_prior(np.random.default_rng(0), 50)
    np.testing.assert_allclose(problem.propagate(x), model.propagate(x, None, np.zeros_like(x)), rtol=1e-12)
    z = case.measurements[0, 3, 0]
    ours = problem.log_likelihood(z, x)
    theirs = model.log_likelihood(np.array([[z]]), x)
    np.testing.assert_allclose(ours - ours.max(), theirs - theirs.max(), rtol=1e-9, atol=1e-9)


def _per_trial_rmse(case, estimates):
    return np.sqrt(np.mean((estimates[..., 0] - case.truth[..., 0]) ** 2, axis=1))


def _assert_same_accuracy(case, estimates, reference, label):
    """Paired per-trial altitude RMSE: mean difference within Z standard errors of 0.

    Both are the same bootstrap filter on the same measurements with independent random
    numbers, so the per-trial RMSE difference has mean zero; its standard error is estimated
    from the trials themselves.
    """
    difference = _per_trial_rmse(case, estimates) - _per_trial_rmse(case, reference)
    se = difference.std(ddof=1) / np.sqrt(len(difference))
    assert abs(difference.mean()) < Z * se, f"{label}: mean RMSE difference {difference.mean():.2f}, SE {se:.2f}"


@pytest.fixture(scope="module")
def accuracy_case():
    case = make_case(400, 60)
    return case, run_pfx(None, case)


def test_reference_filter_is_as_accurate_as_pfx(accuracy_case):
    case, pfx_estimates = accuracy_case
    problem = FallingBodyProblem.from_cell(case.cell)
    reference = run_numpy(problem, case)
    assert np.all(np.isfinite(reference)) and np.all(np.isfinite(pfx_estimates))
    _assert_same_accuracy(case, reference, pfx_estimates, "numpy reference")


@pytest.mark.parametrize("name", PEERS)
def test_peer_is_as_accurate_as_pfx(accuracy_case, name):
    pytest.importorskip(name, reason=f"{name} is installed only in the benchmark's environment (make bench)")
    case, pfx_estimates = accuracy_case
    estimates = ADAPTERS[name](FallingBodyProblem.from_cell(case.cell), case)
    _assert_same_accuracy(case, estimates, pfx_estimates, name)
