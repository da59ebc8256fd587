"""From traces and tables to numbers a reader compares: the per-trial metrics, the summary
statistics of a cell, the per-step summaries over every trial, paired comparisons between
arms, the gap to a reference filter, and the end-of-run table.

May import :mod:`pfx.numerics`, :mod:`pfx.result_folder`; never a filter, a model or a figure.
"""
