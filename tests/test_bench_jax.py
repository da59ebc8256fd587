"""``pfx bench --backend jax``: the plain JAX reference filter computes what the NumPy one does,
and the harness prints every row. No timing is asserted anywhere.

* The reference (:mod:`pfx.bench.jax_reference`) against the plain NumPy filter
  (:mod:`pfx.bench.reference`) on one trial's measurements, 200 runs each: the two draw from
  different generators (threefry keys, NumPy's PCG64), so they agree within Monte Carlo error
  (backend-invariant checks): the mean log-likelihood and the mean squared altitude error within
  4 standard errors of their difference, in float64 and float32.
* The harness (:mod:`pfx.bench.jax_bench`) on a tiny case with pfx's numpy backend standing in
  for the jax backend (the door is the same): every row runs, the pfx rows are compared with the
  reference, the numpy column runs a subset of the trials when capped, a row pfx refuses says
  "not available: <why>", a case that would not fit is skipped with the reason.
* The bandwidth limit's arithmetic (the issue's 3.4e10 and 6.7e10 particle-steps/s on an H200).
* The command line: ``--backend`` other than numpy or jax, and JAX missing, are one line and exit 2.
"""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")

from pfx.bench import jax_bench, run_jax_bench  # noqa: E402
from pfx.bench.jax_bench import IMPLEMENTATIONS, Implementation, Row, time_jax_case  # noqa: E402
from pfx.bench.jax_device import Device, bytes_per_particle_step, known_bandwidth  # noqa: E402
from pfx.bench.jax_reference import jax_reference_filter  # noqa: E402
from pfx.bench.problem import FallingBodyProblem, bench_filter, make_case  # noqa: E402
from pfx.bench.reference import reference_run  # noqa: E402
from pfx.errors import ConfigError  # noqa: E402

Z = 4.0
RUNS = 200
CPU = Device("cpu", "cpu", 16 * 1024 ** 3, None, "unknown")
# The tiny case the harness tests run (3 trials x N = 50, T = 100): a test that calls the JAX
# reference on its shapes reuses its compiled filter (one compile per shape and precision)
# rather than compiling one of its own; what these tests check does not depend on the size.
TINY_CASE = (50, 3)


@pytest.fixture(scope="module")
def numpy_runs():
    """200 runs of the plain NumPy filter on trial 0's first 10 measurements, N = 1000, and the truth."""
    case = make_case(1_000, 1)
    problem = FallingBodyProblem.from_filter(case.filter)
    measurements, truth = case.measurements[0, :10], case.truth[0, :10, 0]
    runs = [reference_run(problem, measurements, 1_000, np.random.default_rng(10_000 + run)) for run in range(RUNS)]
    squared_errors = np.array([np.mean((estimates[:, 0] - truth) ** 2) for estimates, _ in runs])
    return problem, measurements, truth, np.array([log_likelihood for _, log_likelihood in runs]), squared_errors


def _differ_by_less_than(a: np.ndarray, b: np.ndarray, z: float) -> tuple[bool, float, float]:
    """Whether the means of two independent samples differ by less than z standard errors."""
    difference = a.mean() - b.mean()
    standard_error = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    return abs(difference) < z * standard_error, difference, standard_error


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_jax_reference_agrees_with_the_numpy_reference(numpy_runs, precision):
    problem, measurements, truth, numpy_log_likelihoods, numpy_squared_errors = numpy_runs
    repeated = np.repeat(measurements[None], RUNS, axis=0)
    estimates, log_likelihoods = jax_reference_filter(problem, repeated, 1_000, list(range(RUNS)), precision)
    assert estimates.shape == (RUNS, 10, 3) and log_likelihoods.shape == (RUNS,)
    assert np.all(np.isfinite(estimates)) and np.all(np.isfinite(log_likelihoods))
    agree, difference, error = _differ_by_less_than(log_likelihoods, numpy_log_likelihoods, Z)
    assert agree, f"mean log-likelihood: JAX - NumPy = {difference:.3f}, standard error {error:.3f}"
    squared_errors = np.mean((estimates[..., 0] - truth) ** 2, axis=1)
    agree, difference, error = _differ_by_less_than(squared_errors, numpy_squared_errors, Z)
    assert agree, f"mean squared altitude error: JAX - NumPy = {difference:.1f}, standard error {error:.1f}"
    # the same work: RMSEs within 10 % (the squared errors' sd over 200 runs is about 5 % of their mean)
    assert np.sqrt(squared_errors.mean()) == pytest.approx(np.sqrt(numpy_squared_errors.mean()), rel=0.1)


def test_jax_reference_reruns_give_the_same_numbers_and_seeds_differ():
    particles, trials = TINY_CASE
    case = make_case(particles, trials)
    problem = FallingBodyProblem.from_filter(case.filter)
    repeated = np.repeat(case.measurements[:1], trials, axis=0)     # one trial's measurements, 3 times
    first = jax_reference_filter(problem, repeated, particles, [5, 6, 5])
    again = jax_reference_filter(problem, repeated, particles, [5, 6, 5])
    np.testing.assert_array_equal(first[1], again[1])
    assert first[1][0] == first[1][2] and first[1][0] != first[1][1]     # a trial's numbers are its seed's


def test_bandwidth_limit_arithmetic():
    assert bytes_per_particle_step("float64") == 140 and bytes_per_particle_step("float32") == 72
    h200 = Device("gpu", "NVIDIA H200", 140 * 1024 ** 3, *known_bandwidth("NVIDIA H200"))
    assert h200.limit("float64") == pytest.approx(3.43e10, rel=1e-3)     # the "about 3.4e10"
    assert h200.limit("float32") == pytest.approx(6.67e10, rel=1e-3)
    assert known_bandwidth("NVIDIA H100 80GB HBM3")[0] == 3.35e12
    assert known_bandwidth("NVIDIA A100-SXM4-80GB")[0] == 2.0e12
    assert known_bandwidth("NVIDIA H100 PCIe") is None and known_bandwidth("cpu") is None
    assert CPU.limit("float64") is None


@pytest.fixture
def numpy_for_jax(monkeypatch):
    """pfx's jax rows run the numpy backend through the same door (the harness, not the backend, is tested)."""
    monkeypatch.setattr(jax_bench, "bench_filter", lambda particles, settings=None: bench_filter(particles))


def test_harness_prints_every_row_on_a_tiny_case(numpy_for_jax):
    printed = []
    rows = run_jax_bench(cases=[TINY_CASE], repeats=1, bandwidth=1e11, pmmh=False, echo=printed.append)
    lines = "\n".join(printed).splitlines()
    assert lines[0].startswith("pfx bench --backend jax: falling body")
    assert lines[1].startswith("machine: ") and "jax " in lines[1] and "cores" in lines[1]
    assert [row.implementation for row in rows] == IMPLEMENTATIONS
    for row in rows:
        assert row.note is None and row.runs == 1 and row.trials == 3, row
        assert row.rate > 0 and np.isfinite(row.rmse) and np.isfinite(row.log_likelihood)
    names = [row.implementation.name for row in rows]
    table = lines[lines.index("") + 1:]
    body = [line for line in table if line[17:].startswith(tuple(names))]
    assert len(body) == len(rows)
    for line in body:
        name = next(name for name in names if line[17:].startswith(name))
        fields = line[17 + len(name):].split()
        rate, ns, fraction, ratio, first_call, rmse, log_likelihood, runs = fields
        assert float(rate) > 0 and float(ns) > 0 and int(runs) == 1
        on_device = not name.startswith("pfx numpy")
        # with --bandwidth given, every row on the device has its fraction of the limit (on a CPU,
        # pfx numpy's row too: it runs on the device measured; on a GPU it does not)
        assert fraction.endswith("%") if on_device or jax.default_backend() == "cpu" else fraction == "-"
        assert (ratio != "-") == name.startswith("pfx jax")
        assert (first_call != "-") == on_device
    assert any(line.startswith("(the limit: bandwidth / bytes per particle-step") for line in table)
    goals = table[table.index("goals of the jax backend (rates of the best runs on this machine):") + 1:]
    assert sum(line.startswith("  ") for line in goals) == 7


def test_numpy_rows_run_a_subset_above_their_cap(numpy_for_jax, monkeypatch):
    monkeypatch.setattr(jax_bench, "NUMPY_PARTICLES_PER_STEP", 100)
    case = make_case(*TINY_CASE)
    numpy_row, reference_row = time_jax_case(case, [IMPLEMENTATIONS[0], IMPLEMENTATIONS[3]], CPU, 1, 10.0, {})
    assert (numpy_row.trials, reference_row.trials) == (2, 3)      # 100 // 50 trials of 3
    assert numpy_row.particle_steps == 2 * 50 * 100 and numpy_row.runs == 1


def test_refused_rows_say_why_and_too_large_cases_are_skipped(monkeypatch):
    def refusing(particles, settings=None):
        if settings:
            raise ConfigError("filter.backend: no jax backend here", file="<python>")
        return bench_filter(particles)

    monkeypatch.setattr(jax_bench, "bench_filter", refusing)
    tiny = Device("cpu", "cpu", 1024 ** 2, None, "unknown")        # 1 MiB: 20 x 1000 particles do not fit
    rows = time_jax_case(make_case(1_000, 20), IMPLEMENTATIONS[:3], tiny, 1, 10.0, {})
    assert rows[0].note is None and rows[0].runs == 1
    assert rows[1].note.startswith("skipped: needs about") and rows[2].note.startswith("skipped: needs about")
    rows = time_jax_case(make_case(20, 2), IMPLEMENTATIONS[1:2], CPU, 1, 10.0, {})
    assert rows[0].note.startswith("not available: ConfigError:") and "no jax backend here" in rows[0].note


def test_predicted_long_runs_are_skipped():
    row = Row(make_case(20, 2), Implementation("jax reference float64", "reference", "jax", "float64"), 2)
    # 1 ms a particle-step: 4000 particle-steps take 4 s, over 3 x a 1-second budget
    assert jax_bench._reason_to_skip(row, CPU, 1.0, 1e-3).startswith("skipped: one run would take about 4 s")
    assert jax_bench._reason_to_skip(row, CPU, 2.0, 1e-3) is None


def test_command_line_refuses_an_unknown_backend_and_a_missing_jax(pfx_in_process, monkeypatch):
    result = pfx_in_process("bench", "--backend", "cuda")
    assert result.returncode == 2 and result.stderr.strip() == "pfx: error: --backend: numpy or jax, not 'cuda'"
    monkeypatch.setattr(jax_bench, "jax_missing", lambda: jax_bench.MISSING_JAX)
    result = pfx_in_process("bench", "--backend", "jax", "--quick")
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip().splitlines() == [f"pfx: error: {jax_bench.MISSING_JAX}"]
    assert "pip install 'pfx[jax]'" in result.stderr


def test_the_pmmh_goal_line_divides_the_rows_own_rates():
    """pfx jax with 16 chains over pfx numpy with 1 chain, in chain-iterations per second, and
    whether it reaches the 20 x goal; a case without both rows says it was not measured."""
    from pfx.bench.pmmh import CHAINS, PROBLEMS, PmmhTiming
    from pfx.bench.report import format_pmmh_goal

    problem = PROBLEMS["sv"]()

    def row(name, chains, seconds):
        return PmmhTiming(problem, 1000, name, chains, seconds=seconds, rounds=2, chain_iterations=100)

    line = format_pmmh_goal([row("pfx, 1 chain", 1, 0.012), row(f"pfx jax, {CHAINS} chains", CHAINS, 0.008)], "gpu")
    assert "2000 chain-iterations/s = 24.0 x" in line and "(83/s)" in line and ": met (gpu)" in line
    slow = format_pmmh_goal([row("pfx, 1 chain", 1, 0.012), row(f"pfx jax, {CHAINS} chains", CHAINS, 0.096)], "cpu")
    assert "= 2.0 x" in slow and "not met" in slow
    assert "not measured" in format_pmmh_goal([row("pfx, 1 chain", 1, 0.012)], "cpu")
