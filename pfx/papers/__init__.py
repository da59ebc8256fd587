"""Reports of the source documents, one module per paper (see :mod:`pfx.gallery`).

A report reads ``results/<paper>/`` (CSV, figure files, ``paper.yaml``) and returns the
paper's gallery :class:`~pfx.gallery.Section`. To add one: write ``pfx/papers/<name>.py`` with
a function decorated ``@REPORTS.register("<short-name>")`` and import it here.
"""

from pfx.gallery import REPORTS

# One import per paper (each registers its report), in the order of shared/papers/README.md,
# which is the gallery's order.
from pfx.papers import han_lee  # noqa: E402,F401
from pfx.papers import park_mpf  # noqa: E402,F401
from pfx.papers import bayes_blog  # noqa: E402,F401
from pfx.papers import kim_mcl  # noqa: E402,F401
from pfx.papers import prob_robotics  # noqa: E402,F401

__all__ = ["REPORTS"]
