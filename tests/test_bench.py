"""``pfx bench``: it runs, prints every row, and every implementation does the same work.

No timing is asserted anywhere (speed is what the benchmark reports, as ratios). What is
tested: the command in ``--quick`` mode prints the machine line, a row per case and
implementation, the algorithms table (a row per algorithm, the bootstrap first, a reason on
each row pfx refuses for the model), the memory and workers lines and the goals; the
benchmark's NumPy model is pfx's model; the reference filter (and each peer library that is
installed) estimates the altitude as well as pfx does, trial by trial, within a tolerance
from the standard error; every algorithm of the second table runs, and those that target
the same posterior as the bootstrap estimate the altitude as well as it does.
"""

from __future__ import annotations

from itertools import takewhile

import numpy as np
import pytest

from pfx.bench import QUICK_CASES
from pfx.bench.algorithms import ALGORITHMS, BASELINE, QUICK_CASE, algorithm_filters
from pfx.bench.peers import ADAPTERS, PEERS
from pfx.bench.problem import FallingBodyProblem, make_case
from pfx.bench.report import ALGORITHM_WIDTH, format_table
from pfx.bench.timing import Timing, run_filter, run_numpy, run_pfx

Z = 4.5        # two-sided P(|Z| > 4.5) = 7e-6 per comparison


@pytest.fixture(scope="module")
def quick_output(pfx_in_process):
    # In this process: what is checked is the printed tables, not the process (the bench still
    # starts the processes it measures: the peak-memory run and the pool of 2 workers).
    result = pfx_in_process("bench", "--quick", "--repeats", "1", timeout=600)
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
    assert len(goal_lines) == 9, goal_lines
    assert goal_lines[0].startswith("  N=1e3, 1 trial: pfx time / numpy reference time: goal ")
    assert goal_lines[8].startswith("  one filter: Python entry point time / config path time: goal ")


def test_quick_bench_prints_the_small_filters_table(quick_output):
    """One trial of the plugin-style stochastic-volatility model: pfx and the NumPy loop (and
    particles where installed) did the same work: their log-variance RMSEs agree."""
    lines = quick_output.splitlines()
    title = next(i for i, line in enumerate(lines) if line.startswith("small filters: stochastic volatility"))
    rows = {line[16:].split()[0]: line[16:].split()[1:] for line in lines[title + 3:title + 7]
            if line.strip() and not line.startswith("(")}
    assert {"pfx", "numpy"} <= set(rows)
    milliseconds, per_step, ratio, rmse, runs = rows["pfx"]
    assert float(ratio) == 1.0 and float(milliseconds) > 0 and int(runs) == 1
    # both filter the same 200 returns with N = 100: their RMSEs against the true log-variance
    # differ by Monte Carlo error only (0.4 here; a filter doing less work would be far off)
    assert abs(float(rows["numpy"][3]) - float(rmse)) < 0.1
    assert any(line.startswith("one falling-body filter, N=100, 1 trial: through the Python entry point")
               for line in lines)


# Rows the falling body cannot have, each with a word of pfx's reason: the radar's range is
# not linear in the state.
NOT_APPLICABLE = {"locally_optimal proposal": "linear"}


def test_quick_bench_prints_the_algorithms_table(quick_output):
    lines = quick_output.splitlines()
    particles, trials = QUICK_CASE
    title = next(i for i, line in enumerate(lines) if line.startswith("algorithms against the bootstrap"))
    assert f"{trials} x N={particles}" in lines[title]
    header = lines[title + 1].split()
    assert header[:2] == ["algorithm", "ns/particle-step"] and "bootstrap" in header and header[-1] == "runs"
    rows = lines[title + 3:title + 3 + len(ALGORITHMS)]
    names = [line[:ALGORITHM_WIDTH].strip() for line in rows]
    assert names == list(ALGORITHMS) and names[0] == BASELINE
    for name, line in zip(names, rows):
        cells = line[ALGORITHM_WIDTH:].split()
        if name in NOT_APPLICABLE:
            assert cells[:2] == ["not", "applicable:"], line
            reason = " ".join(cells[2:])
            assert NOT_APPLICABLE[name] in reason, line
            continue
        assert cells[0] not in ("failed:", "not"), line
        ns, ratio, rmse, mean_particles, runs = map(float, cells)
        assert ns > 0 and ratio > 0 and np.isfinite(rmse) and 0 < mean_particles <= particles and runs == 1, line
        if name == BASELINE:
            assert ratio == 1.0 and mean_particles == particles, line
    assert lines[title + 3 + len(ALGORITHMS)].startswith("augmented injection: ")


def test_bench_model_is_pfx_model():
    """The NumPy functions the reference and the peers use are pfx's falling body (Euler, dt 0.1)."""
    case = make_case(50, 1)
    model = case.filter.model
    problem = FallingBodyProblem.from_filter(case.filter)
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
    problem = FallingBodyProblem.from_filter(case.filter)
    reference = run_numpy(problem, case)
    assert np.all(np.isfinite(reference)) and np.all(np.isfinite(pfx_estimates))
    _assert_same_accuracy(case, reference, pfx_estimates, "numpy reference")


@pytest.mark.parametrize("name", PEERS)
def test_peer_is_as_accurate_as_pfx(accuracy_case, name):
    pytest.importorskip(name, reason=f"{name} is installed only in the benchmark's environment (make bench)")
    case, pfx_estimates = accuracy_case
    estimates = ADAPTERS[name](FallingBodyProblem.from_filter(case.filter), case)
    _assert_same_accuracy(case, estimates, pfx_estimates, name)


# The algorithms that target the same posterior as the bootstrap filter (a guided proposal
# with its importance correction, the auxiliary filter's two stages, a Metropolis move that
# leaves the step's target invariant): on the same measurements they estimate the altitude as
# well as the bootstrap, within Z standard errors of the paired per-trial difference. (A loose
# check: at finite N their Monte Carlo errors differ a little, which 60 trials cannot show.)
# Not asserted: the regularise move (its kernel at the "optimal" bandwidth widens the
# posterior, measurably so here), KLD-sampling (fewer particles than N) and augmented
# injection (prior draws in place of particles when the likelihood drops): different filters.
CONSISTENT = ["ekf proposal", "ukf proposal", "auxiliary (APF)", "mcmc move"]


@pytest.fixture(scope="module")
def algorithm_traces(accuracy_case):
    case, _ = accuracy_case
    filters = algorithm_filters(case.particles)
    return {name: bound if isinstance(bound, str) else run_filter(bound, case) for name, bound in filters.items()}


def test_every_algorithm_runs_or_says_why_not(accuracy_case, algorithm_traces):
    case, pfx_estimates = accuracy_case
    assert list(algorithm_traces) == list(ALGORITHMS)
    for name, trace in algorithm_traces.items():
        if name in NOT_APPLICABLE:
            assert isinstance(trace, str) and NOT_APPLICABLE[name] in trace, (name, trace)
            continue
        assert not isinstance(trace, str), (name, trace)
        assert trace.estimates.shape == pfx_estimates.shape and np.all(np.isfinite(trace.estimates)), name
        counts = trace.particle_counts
        assert counts is not None and np.all((counts >= 1) & (counts <= case.particles)), name
    # the baseline row is the first table's pfx filter: the same cell, the same random numbers
    np.testing.assert_array_equal(algorithm_traces[BASELINE].estimates, pfx_estimates)
    kld = algorithm_traces["kld adaptive"].particle_counts
    assert kld.min() >= ALGORITHMS["kld adaptive"]["adaptive"]["min_particles"]


@pytest.mark.parametrize("name", CONSISTENT)
def test_algorithm_is_as_accurate_as_the_bootstrap(accuracy_case, algorithm_traces, name):
    case, pfx_estimates = accuracy_case
    _assert_same_accuracy(case, algorithm_traces[name].estimates, pfx_estimates, name)


# -- PMMH against particles' PMMH (pfx/bench/pmmh.py) ------------------------------------------

def _pmmh_rows(lines):
    """The PMMH table's rows: {case label: {implementation: [numbers]}}, and its other lines."""
    from pfx.bench.report import PMMH_CASE_WIDTH, PMMH_NAME_WIDTH

    title = next(i for i, line in enumerate(lines) if line.startswith("PMMH: milliseconds per iteration"))
    end = next(i for i in range(title, len(lines)) if lines[i].startswith("(particles' PMMH runs one chain"))
    rows, notes, label = {}, [], None
    for line in lines[title + 3:end]:
        if line.startswith("  ") and line[2] != " " or line.strip().startswith("particles: not installed"):
            notes.append(line.strip())      # the lines under a case's rows, indented by two
            continue
        label = line[:PMMH_CASE_WIDTH].strip() or label
        name = line[PMMH_CASE_WIDTH:PMMH_CASE_WIDTH + 1 + PMMH_NAME_WIDTH].strip()
        rows.setdefault(label, {})[name] = line[PMMH_CASE_WIDTH + 1 + PMMH_NAME_WIDTH:].split()
    return lines[title], rows, notes


def test_quick_bench_prints_the_pmmh_table(quick_output):
    """Both problems at the quick size: pfx with 1 chain and with 16 chains, on numpy and on jax
    (and particles where installed), with jax's speed-up over numpy; per chain-iteration is per iteration over the chains; where a pfx iteration goes
    adds up to the iteration (the rest is what the clocked stages leave, never negative)."""
    from pfx.bench.pmmh import CHAINS, PROBLEMS, QUICK_SIZES, STAGES, jax_installed
    from pfx.bench.pmmh import implementations as bench_rows

    title, rows, notes = _pmmh_rows(quick_output.splitlines())
    assert "best of 1 rounds" in title and "load average" in title
    labels = [f"{make().label}, N={particles}" for make in PROBLEMS.values() for particles in QUICK_SIZES]
    assert list(rows) == labels
    pfx_rows = bench_rows(with_particles=False)
    for label in labels:
        implementations = rows[label]
        for name, chains in pfx_rows:
            milliseconds, per_chain, ratio, filters, accepted, rounds = implementations[name]
            assert float(milliseconds) > 0 and int(rounds) == 1, (label, name)
            assert abs(float(per_chain) * chains - float(milliseconds)) <= 0.0005 * chains + 0.005, (label, name)
            # the starts lie inside the priors and the steps are small: every proposal runs a filter or
            # is refused by the prior; the acceptance is a share of the chain-iterations
            assert 0 < float(filters) <= 1 and 0 <= float(accepted) <= 1, (label, name)
        if "particles, 1 chain" in implementations:
            assert float(implementations["particles, 1 chain"][2]) == 1.0
        else:
            assert any(note.startswith("particles: not installed") for note in notes)
    stage_lines = [note for note in notes if note.startswith("where a pfx iteration goes")]
    assert len(stage_lines) == len(pfx_rows) * len(labels)
    speed_lines = [note for note in notes if note.startswith("jax over numpy, chain-iterations per second")]
    assert len(speed_lines) == (len(labels) if jax_installed() else 0)
    for note in speed_lines:        # the ratio of the rows' own numbers
        assert "1 chain " in note and f"{CHAINS} chains " in note, note
    for note in stage_lines:
        parts = dict(part.rsplit(" ", 1) for part in note.split("(ms): ")[1].split(", "))
        assert list(parts) == list(STAGES) and all(float(value) >= 0 for value in parts.values()), note
    likelihood_lines = [note for note in notes if note.startswith("log-likelihood estimates at the start")]
    assert len(likelihood_lines) == len(labels)
    assert "exact (Kalman)" in next(line for label, line in zip(labels, likelihood_lines) if label.startswith("Nile"))


def test_pmmh_problems_run_batched_from_their_starts():
    """The bench times the batched path (the chains one batch of the engine), on the data named,
    from the published starting points."""
    from pfx.bench.pmmh import DURBIN_KOOPMAN, PITT_SHEPHARD, PROBLEMS, build_target, start_values

    starts = {"sv": list(PITT_SHEPHARD.values()), "nile": [DURBIN_KOOPMAN["measurement"], DURBIN_KOOPMAN["level"]]}
    for name, make in PROBLEMS.items():
        problem = make()
        target, _ = build_target(problem, particles=50, chains=4, iterations=2)
        assert target.batched, name
        assert target.measurements.shape == (problem.steps, 1) and np.all(np.isfinite(target.measurements)), name
        np.testing.assert_array_equal(start_values(target), starts[name])
        assert len(problem.peer_names) == target.dimension


def test_natural_scale_sds_are_the_walks_first_steps():
    r"""particles walks on theta itself: its standard deviations are pfx's on u = g(theta) times
    |d theta / du| at the start (none: 1; log: theta; logit on (a, b): (theta - a)(b - theta)/(b - a))."""
    from pfx.bench.pmmh import PROBLEMS, build_target, natural_scale_sds

    sv, _ = build_target(PROBLEMS["sv"](), particles=50, chains=1, iterations=2)
    mu, phi, sigma = (sv.estimation.parameters[path] for path in sv.paths)
    expected = [mu.proposal_sd, phi.proposal_sd * phi.start * (1.0 - phi.start), sigma.proposal_sd * sigma.start]
    np.testing.assert_allclose(natural_scale_sds(sv), expected, rtol=1e-12)
    nile, _ = build_target(PROBLEMS["nile"](), particles=50, chains=1, iterations=2)
    expected = []
    for path in nile.paths:
        parameter = nile.estimation.parameters[path]
        lower, upper = parameter.prior.lower, parameter.prior.upper
        expected.append(parameter.proposal_sd * (parameter.start - lower) * (upper - parameter.start) / (upper - lower))
    np.testing.assert_allclose(natural_scale_sds(nile), expected, rtol=1e-12)


@pytest.mark.parametrize("name", ["sv", "nile"])
def test_particles_pmmh_peer_computes_pfx_likelihood(name):
    """particles' model and data in the PMMH comparison give pfx's likelihood: at the start, the
    means of 40 log-likelihood estimates each (N = 1000) agree within Z standard errors, plus the
    difference of the two estimators' Jensen biases, about (s_pfx^2 - s_particles^2) / 2."""
    pytest.importorskip("particles", reason="particles is installed only in the benchmark's environment (make bench)")
    import particles
    from particles import state_space_models

    from pfx.bench.peers import global_generator_seeded
    from pfx.bench.pmmh import PROBLEMS, _peer_problem, build_target, start_values

    runs, count = 40, 1000
    problem = PROBLEMS[name]()
    target, _ = build_target(problem, particles=count, chains=runs, iterations=2)
    ours = target.log_likelihoods(np.repeat(start_values(target)[None], runs, axis=0), list(range(runs)))
    pieces = _peer_problem(problem, target)
    start = {entry[0]: float(pieces["start"][entry[0]][0]) for entry in pieces["prior"].dtype}
    theirs = []
    with global_generator_seeded(problem.seed):
        for _ in range(runs):
            smc = particles.SMC(fk=state_space_models.Bootstrap(ssm=pieces["model"](**start), data=pieces["data"]),
                                N=count, collect="off")
            smc.run()
            theirs.append(smc.logLt)
    theirs = np.array(theirs)
    se = np.sqrt(ours.var(ddof=1) / runs + theirs.var(ddof=1) / runs)
    bias = abs(ours.var(ddof=1) - theirs.var(ddof=1)) / 2
    assert abs(ours.mean() - theirs.mean()) < Z * se + bias, (ours.mean(), theirs.mean(), se, bias)


def test_a_case_whose_implementations_disagree_on_the_rmse_gets_a_note():
    """One trial at N = 100 may lose the falling body in one implementation's draws and not in
    another's: the table says why, under the case, rather than leaving 3,972 ft beside 106 ft."""
    case = make_case(100, 1)
    apart = [Timing(case, "pfx", 0.1, 3, rmse=3971.7), Timing(case, "numpy", 0.1, 3, rmse=106.1)]
    close = [Timing(case, "pfx", 0.1, 3, rmse=82.8), Timing(case, "numpy", 0.1, 3, rmse=113.7)]
    assert "draws its own random numbers" in format_table(apart)
    assert "draws its own random numbers" not in format_table(close)

