"""From traces and tables to numbers a reader compares: the per-trial metrics, the summary
statistics of a cell, the per-step summaries over every trial, paired comparisons between
arms, the gap to a reference filter, the end-of-run table, and the flags on estimation runs'
chains and replicates (:mod:`pfx.analysis.estimation_flags`).

May import :mod:`pfx.numerics`, :mod:`pfx.result_folder`; never a filter, a model or a figure.
"""
