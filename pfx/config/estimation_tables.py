"""The columns of an estimation run's tables, in one place: the writers build their rows from
these layouts, and a parameter may not take the name of one of their columns.

Every table starts with the cell's columns (``cell``, then its labels: ``arm``, ``model``,
``filter``, ..., the swept keys), as trials.csv does. chains.csv, if2.csv,
maximum_likelihood.csv and likelihood_spread.csv (a flagged PMMH cell's spread of the
log-likelihood estimate, at the point its parameter columns give) then have their own columns,
one column per estimated parameter (named
by :meth:`pfx.config.estimation.EstimationConfig.column`) among them; the progress files
``estimation/<cell>.csv`` are chains.csv's and if2.csv's columns without the cell's.
posterior.csv and priors.csv have one row per parameter instead, its name in ``parameter``, and
posterior.csv one more row for the log-likelihood.

A parameter named like one of these columns would overwrite it (a parameter called
``log_likelihood`` replaces the chains' log-likelihoods with its values), so
:func:`reserved_names` is refused as a parameter's name: the set comes from the layouts
themselves, and a test checks that the written tables have exactly these columns.
"""

from __future__ import annotations

from dataclasses import dataclass

CELL = "cell"


@dataclass(frozen=True)
class TableLayout:
    """A table with a column per parameter: its columns before and after the parameters'."""

    file: str
    before: tuple[str, ...]
    after: tuple[str, ...]

    def progress_columns(self, parameters: list[str]) -> list[str]:
        """The columns without the cell's (a progress file's)."""
        return [*self.before, *parameters, *self.after]

    def columns(self, labels: list[str], parameters: list[str]) -> list[str]:
        return [CELL, *labels, *self.progress_columns(parameters)]

    @property
    def own(self) -> tuple[str, ...]:
        return (*self.before, *self.after)


CHAINS = TableLayout("chains.csv", ("chain", "iteration", "warm_up"), ("log_likelihood", "log_prior", "accepted"))
IF2 = TableLayout("if2.csv", ("replicate", "iteration"), ("log_likelihood",))
MAXIMUM_LIKELIHOOD = TableLayout("maximum_likelihood.csv", ("replicate",), ("log_likelihood", "log_likelihood_se", "flag"))
# likelihood_spread.csv: a flagged particle-filter cell's sd of the log-likelihood estimate, measured at
# its posterior mean (the parameters' columns: the point); written only where a cell was measured
LIKELIHOOD_SPREAD = TableLayout("likelihood_spread.csv", (),
                                ("particles", "runs", "finite", "mean", "sd", "sd_standard_error", "run_time_s"))
# particle_count.csv (PMMH with `particles: auto`): a row per particle count the pilot measured, no
# parameter columns, so its names are not reserved (a parameter's column is never beside them; the
# cell's label columns are `arm`, ... and swept keys with a dot made `_`, never one of these)
# the folder's particle_count.csv has, between the cell's columns and these, the pilot's `stage`
PARTICLE_COUNT_STAGES = ("before_chains", "after_warm_up")
PARTICLE_COUNT = TableLayout("particle_count.csv", ("particles", "runs", "finite", "mean", "sd", "sd_standard_error",
                                                    "run_time_s", "chosen"), ())
# profile.csv (method: profile): a row per grid value and start, the profiled parameter's column first
# among the parameters'; profile_interval.csv and profile_smoothed.csv have no parameter columns
PROFILE = TableLayout("profile.csv", ("grid_point", "start"), ("log_likelihood", "log_likelihood_se"))
PROFILE_INTERVAL_COLUMNS = ("parameter", "level", "span", "estimates", "maximum", "log_likelihood_maximum",
                            "cutoff", "lower", "upper", "se_statistical", "se_monte_carlo", "flag")
PROFILE_SMOOTHED_COLUMNS = ("parameter", "value", "smoothed_log_likelihood")

# posterior.csv: a row per parameter and one for the log-likelihood; the quantiles by their probability
QUANTILES = {"quantile_2_5": 0.025, "quantile_25": 0.25, "median": 0.5, "quantile_75": 0.75, "quantile_97_5": 0.975}
DIAGNOSTICS = ("r_hat", "ess_bulk", "ess_tail", "mcse_mean")
# flag: the checks the row fails, empty if none (pfx.analysis.estimation_flags)
POSTERIOR_COLUMNS = ("parameter", "n", "mean", "sd", *QUANTILES, *DIAGNOSTICS, "acceptance_rate", "chains", "flag")
POSTERIOR_EXTRA_ROWS = ("log_likelihood",)
PRIORS_COLUMNS = ("parameter", "value", "density")


def tables_with(name: str) -> list[str]:
    """The tables in which ``name`` is a column (or, in posterior.csv, a row of its own)."""
    found = [layout.file for layout in (CHAINS, IF2, MAXIMUM_LIKELIHOOD, LIKELIHOOD_SPREAD, PROFILE)
             if name in (CELL, *layout.own)]
    if name in (CELL, *POSTERIOR_COLUMNS, *POSTERIOR_EXTRA_ROWS):
        found.append("posterior.csv")
    if name in PRIORS_COLUMNS:
        found.append("priors.csv")
    return found


def reserved_names() -> set[str]:
    """Every name a parameter may not take, whatever the cell's labels (see the module docstring)."""
    return {CELL, *CHAINS.own, *IF2.own, *MAXIMUM_LIKELIHOOD.own, *LIKELIHOOD_SPREAD.own, *POSTERIOR_COLUMNS, *POSTERIOR_EXTRA_ROWS,
            *PRIORS_COLUMNS, *PROFILE.own}
