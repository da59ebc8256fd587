"""Reports of the source documents, one module per paper; the gallery renders them.

A report reads ``results/<paper>/`` (CSV, figure files, ``paper.yaml``) and returns the
paper's gallery :class:`~pfx.papers.base.Section`. Each report is an ordered tuple of part
functions put together by :func:`pfx.papers.base.assemble` (see :mod:`pfx.papers.base`). To
add one: write ``pfx/papers/<name>.py`` in that shape, importing :mod:`pfx.papers.base` only,
with its report function decorated ``@REPORTS.register("<short-name>")``; import it here; put
its short name in :data:`GALLERY_ORDER`; describe the document in ``docs/papers/<short-name>.md``.
A benchmark of the field (:data:`BENCHMARK_ORDER`) is a report of the same shape, whose configs
live in ``configs/benchmarks/<short-name>/`` and whose setup is described in
``docs/benchmarks/<short-name>.md``.
"""

from pfx.papers import (  # noqa: F401  (register the reports)
    bayes_blog,
    beyond_the_papers,
    dacca_cholera,
    dapper_lorenz,
    estimation_nile,
    estimation_sv,
    han_lee,
    kim_mcl,
    measles_london,
    park_mpf,
    prob_robotics,
    sv_gbp_usd,
)
from pfx.papers.base import REPORTS

# The gallery's order: the order of the source documents' list, not of the imports above; then
# the section beyond them (filter algorithms none of the documents compares).
GALLERY_ORDER = ("han-lee", "park-mpf", "bayes-blog", "kim-mcl", "prob-robotics", "beyond-the-papers")

# The field's published benchmarks (configs/benchmarks/<name>/ -> results/benchmarks/<name>/,
# `make reproduce-benchmarks`): their own gallery, results/benchmarks/README.md, in this order.
BENCHMARK_ORDER = ("dapper-lorenz", "sv-gbp-usd", "dacca-cholera", "measles-london", "estimation-nile",
                   "estimation-sv")

__all__ = ["BENCHMARK_ORDER", "GALLERY_ORDER", "REPORTS"]
