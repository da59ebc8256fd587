"""Extract London's weekly measles reports, births and population from pypomp, once.

He, Ionides & King (2010, *J. R. Soc. Interface* 7:271-283) fitted an SEIR model to the weekly
measles case reports of London, 1950-1963 (the week's reports dated 1950-01-06 to 1963-12-27,
730 weeks), driven by the city's annual births and population. R's ``pomp`` (its He et al.
lessons) and its Python port ``pypomp`` (MIT licence) ship the data; pypomp 1.1.0 holds them
under ``pypomp/data/uk_measles/`` (``measles.csv.gz``: date, unit, cases for the towns of
England and Wales; ``demog.csv``: year, unit, pop, births), as Korevaar, Metcalf & Grenfell
(2020) compiled them. This script writes, for London:

* ``examples/data/london-measles-cases.csv``: ``time`` and ``cases``, the 730 weeks exactly as
  the source has them. ``time`` is pypomp's (and pomp's): 1950 + (days since 1950-01-01) /
  365.25, printed with Python's shortest round-trip repr;
* ``examples/data/london-measles-cases-he2010.csv``: the same with He et al.'s one correction
  for London: the week of 1955-08-26 reports 0 cases in the middle of an epidemic (124, 82, 0,
  58, 38), an obvious recording error, which He et al. replaced by 76 (pypomp's
  ``UKMeasles.subset(clean=True)`` records the value in a comment and blanks the week instead).
  The benchmark filters this file, the data of the published likelihood;
* ``examples/data/london-measles-demography.csv``: ``year``, ``pop``, ``births`` (1944-1964), as
  the source has them;
* ``examples/data/london-measles-covariates.csv``: ``time``, ``pop``, ``birthrate``, the table
  pypomp's model reads (``UKMeasles.pomp(...).covars``), values unchanged: on a monthly grid
  from 1944, ``pop`` is a smoothing spline through the annual populations and ``birthrate``
  one through the annual births placed at mid-year, read 4 years earlier (He et al.'s delay from
  birth to entering the susceptible pool of school children), both extended linearly beyond
  the data's years (pypomp: ``scipy.interpolate.make_smoothing_spline``; pomp: R's
  ``smooth.spline``, whose penalty choice differs slightly).

It checks that the two cases files differ only in that week, that the weeks are 7/365.25 apart
and that the covariate table's times are monthly. Run it once, from the repository's root, in an
environment with pypomp (pfx never imports this script, pypomp or its JAX)::

    python -m venv /tmp/venv-pypomp && /tmp/venv-pypomp/bin/pip install pypomp==1.1.0
    /tmp/venv-pypomp/bin/python examples/benchmarks/measles_extract.py
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

TOWN = "London"
FIRST_YEAR, LAST_YEAR = 1950, 1963             # He et al.'s years (pypomp's defaults)
CORRECTED_DATE, CORRECTED_CASES = "1955-08-26", 76     # He et al.'s replacement of a recorded 0
WEEK = 7.0 / 365.25
MONTH = 1.0 / 12.0
SPACING_TOLERANCE = 1e-9


def write_table(path: Path, rows: list[list]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        csv.writer(handle, lineterminator="\n").writerows(rows)


def number(value) -> str:
    """A float as its shortest round-trip text; a whole number without a decimal point."""
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 2**53 else repr(value)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("examples/data"), help="output folder")
    arguments = parser.parse_args(argv)

    import pandas as pd
    from pypomp.core.parameters import PompParameters
    from pypomp.models.measles.uk_measles import UKMeasles

    data = UKMeasles.subset([TOWN])
    weeks = data["measles"].copy()
    weeks = weeks[(weeks["date"].dt.year >= FIRST_YEAR) & (weeks["date"].dt.year <= LAST_YEAR)]
    weeks["time"] = (weeks["date"] - pd.Timestamp(f"{FIRST_YEAR}-01-01")).dt.days / 365.25 + FIRST_YEAR
    weeks = weeks[(weeks["time"] > FIRST_YEAR) & (weeks["time"] < LAST_YEAR + 1)].reset_index(drop=True)
    spacings = weeks["time"].diff().dropna()
    if (spacings - WEEK).abs().max() > SPACING_TOLERANCE:
        raise SystemExit("the weeks are not 7/365.25 years apart")

    # pypomp's own covariate table and data for London (the parameters only fill its form).
    parameters = PompParameters({name: 1.0 for name in UKMeasles._MODELS["001"].param_names})
    model = UKMeasles.pomp(TOWN, parameters, model="001")
    if list(model.ys["cases"]) != list(weeks["cases"]) or not all(
            abs(a - b) < SPACING_TOLERANCE for a, b in zip(model.ys.index, weeks["time"])):
        raise SystemExit("pypomp's London series differs from the one read here")
    covariates = model.covars
    if (pd.Series(covariates.index).diff().dropna() - MONTH).abs().max() > SPACING_TOLERANCE:
        raise SystemExit("the covariate table is not monthly")

    cases = [["time", "cases"]] + [[number(t), number(c)] for t, c in zip(weeks["time"], weeks["cases"])]
    corrected_rows = [index for index, date in enumerate(weeks["date"]) if str(date.date()) == CORRECTED_DATE]
    if len(corrected_rows) != 1 or weeks["cases"][corrected_rows[0]] != 0:
        raise SystemExit(f"expected one week {CORRECTED_DATE} with 0 cases")
    corrected = [list(row) for row in cases]
    corrected[1 + corrected_rows[0]][1] = str(CORRECTED_CASES)
    demography = data["demog"]
    write_table(arguments.out / "london-measles-cases.csv", cases)
    write_table(arguments.out / "london-measles-cases-he2010.csv", corrected)
    write_table(arguments.out / "london-measles-demography.csv",
                [["year", "pop", "births"]] + [[number(y), number(p), number(b)] for y, p, b in
                                               zip(demography["year"], demography["pop"], demography["births"])])
    write_table(arguments.out / "london-measles-covariates.csv",
                [["time", "pop", "birthrate"]] + [[number(t), number(p), number(b)] for t, p, b in
                                                  zip(covariates.index, covariates["pop"], covariates["birthrate"])])
    print(f"{len(cases) - 1} weeks ({weeks['date'].iloc[0].date()} to {weeks['date'].iloc[-1].date()}), "
          f"{len(demography)} years of demography, {len(covariates)} monthly covariate rows "
          f"({covariates.index[0]:.4f} to {covariates.index[-1]:.4f}); t0 = {float(2 * weeks['time'][0] - weeks['time'][1])!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
