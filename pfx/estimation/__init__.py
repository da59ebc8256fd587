"""Parameter estimation from the data: the model's parameters, not its state.

* :mod:`pfx.estimation.target`: the log-likelihood estimate of a cell's filter at given
  parameter values (many rows in one batch of the engine), the priors and transforms;
* :mod:`pfx.estimation.pmmh`: particle marginal Metropolis-Hastings, many chains at once;
* :mod:`pfx.estimation.if2`: iterated filtering (IF2), maximum likelihood;
* :mod:`pfx.estimation.summary`: the posterior's summary and diagnostics (ArviZ's, through
  arviz-stats) with their flags, the likelihood's spread at a flagged cell's posterior mean,
  the prior densities for the figures.

Its layer sits between :mod:`pfx.config` (the ``estimation:`` section, the plan of cells) and
:mod:`pfx.run` (which runs a plan into its result folder, :mod:`pfx.run.estimation`); it
imports the first, never the second (docs/layout.md, docs/estimation.md).
"""
