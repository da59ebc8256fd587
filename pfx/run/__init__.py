"""Running a plan: a batch of trials of one cell (:mod:`pfx.run.batch`), the orchestration that
splits cells into batches, hands them to an executor and writes the result folder
(:mod:`pfx.run.runner`), the memory budget, and the executors (this process, local worker
processes, a Dask cluster).

May import everything below it (config, figures, studies, analysis, filters, models); only the
command line, the benchmark and the papers import it.
"""
