"""Reports of the source documents, one module per paper (see :mod:`pfx.papers.gallery`).

A report reads ``results/<paper>/`` (CSV, figure files, ``paper.yaml``) and returns the
paper's gallery :class:`~pfx.papers.gallery.Section`. To add one: write
``pfx/papers/<name>.py`` with a function decorated ``@REPORTS.register("<short-name>")``, import
it here, and put its short name in :data:`GALLERY_ORDER`.
"""

from pfx.papers import bayes_blog, han_lee, kim_mcl, park_mpf, prob_robotics  # noqa: F401  (register the reports)
from pfx.papers.gallery import REPORTS

# The gallery's order: the order of the source documents' list, not of the imports above.
GALLERY_ORDER = ("han-lee", "park-mpf", "bayes-blog", "kim-mcl", "prob-robotics")

__all__ = ["GALLERY_ORDER", "REPORTS"]
