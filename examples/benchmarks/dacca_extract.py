"""Extract the Dhaka (Dacca) cholera data and covariates from the pypomp wheel, once.

King, Ionides, Pascual & Bouma (2008, *Nature* 454:877-880) fitted a stochastic SIRS model to
the monthly cholera deaths of the Dacca district of Bengal, 1891-1940. R's ``pomp`` package
ships the model and data as its ``dacca`` example (the deaths courtesy of M. J. Bouma); the
Python package ``pypomp`` (MIT licence) ships the same series, and the covariate table pomp
builds for it, as CSV files under ``pypomp/data/dacca/``. This script copies them into pfx's
recorded-data format, **as text, without changing a value**:

* ``examples/data/dacca-deaths.csv``: ``time`` (decimal years, the end of each month:
  1891 + 1/12, ..., 1941, as the source prints them) and ``cholera_deaths`` (the monthly count),
  600 rows, from ``dacca.csv``'s ``time`` and ``cholera.deaths`` columns;
* ``examples/data/dacca-covariates.csv``: ``time`` (1891.00, 1891.01, ..., 1941.16: the source's
  grid of 0.01 year, kept) and the nine covariates ``trend``, ``dpopdt``, ``pop``,
  ``seas_1`` .. ``seas_6``, 5017 rows, from ``covars.csv`` with its times from ``covart.csv``.

How pomp builds the covariates (R/dacca.R), for the record: on the grid t = t0, t0 + 0.01, ...
(t0 = 1891), ``pop`` is a smoothing spline through the six censuses 1891-1941 and ``dpopdt``
its derivative, ``trend`` is t minus the grid's mean, and ``seas_1..6`` is a periodic cubic
B-spline basis of period one year evaluated at t - 1/12. pfx (like pomp) interpolates the table
linearly in time.

The script checks what it can against the other files of the same wheel: the deaths equal
``cholera.csv``'s ``Dacca`` column, the times are 1891 + k/12 and the covariate times
t0 + 0.01 i (to the source's printing precision). It never imports pypomp (nor JAX): it reads
the wheel as a zip archive. Run it once, from the repository's root::

    pip download --no-deps pypomp==1.1.0 -d /tmp/pypomp
    python examples/benchmarks/dacca_extract.py /tmp/pypomp/pypomp-1.1.0-py3-none-any.whl

pfx never imports this script.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
import zipfile
from pathlib import Path

SOURCE_FOLDER = "pypomp/data/dacca/"
DEATHS_FILE = "dacca-deaths.csv"
COVARIATES_FILE = "dacca-covariates.csv"
INITIAL_TIME = 1891.0             # pomp's t0: one month before the first observation
COVARIATE_SPACING = 0.01          # the source's covariate grid (years)
PRINTED_PRECISION = 1e-9          # the source prints 15 significant digits: years to ~1e-11


def read_source_table(wheel: zipfile.ZipFile, name: str) -> list[list[str]]:
    """Rows (header first) of one CSV file of the wheel's dacca folder, as text."""
    with wheel.open(SOURCE_FOLDER + name) as handle:
        return list(csv.reader(io.TextIOWrapper(handle, encoding="utf-8")))


def extracted_deaths(wheel: zipfile.ZipFile) -> list[list[str]]:
    """The rows ``time, cholera_deaths`` (header first), checked against cholera.csv."""
    table = read_source_table(wheel, "dacca.csv")
    header, rows = table[0], table[1:]
    time_column, deaths_column = header.index("time"), header.index("cholera.deaths")
    raw = read_source_table(wheel, "cholera.csv")
    raw_deaths = [row[raw[0].index("Dacca")] for row in raw[1:]]
    deaths = [row[deaths_column] for row in rows]
    if deaths != raw_deaths:
        raise SystemExit("dacca.csv's cholera.deaths differ from cholera.csv's Dacca column")
    for month, row in enumerate(rows, start=1):
        if abs(float(row[time_column]) - (INITIAL_TIME + month / 12.0)) > PRINTED_PRECISION:
            raise SystemExit(f"dacca.csv row {month}: time {row[time_column]} is not 1891 + {month}/12")
        if not row[deaths_column].isdigit():
            raise SystemExit(f"dacca.csv row {month}: deaths {row[deaths_column]!r} is not a count")
    return [["time", "cholera_deaths"]] + [[row[time_column], row[deaths_column]] for row in rows]


def extracted_covariates(wheel: zipfile.ZipFile) -> list[list[str]]:
    """The rows ``time, trend, dpopdt, pop, seas_1..seas_6`` (header first): covars.csv's
    values with covart.csv's times, row by row (both number their rows 1..n)."""
    values = read_source_table(wheel, "covars.csv")
    times = read_source_table(wheel, "covart.csv")
    if len(values) != len(times):
        raise SystemExit(f"covars.csv has {len(values) - 1} rows, covart.csv {len(times) - 1}")
    names = values[0][1:]
    rows = []
    for index, (value_row, time_row) in enumerate(zip(values[1:], times[1:]), start=1):
        if value_row[0] != f"V{index}" or time_row[0] != str(index):
            raise SystemExit(f"row {index}: the files' row names {value_row[0]!r}, {time_row[0]!r} do not pair")
        if abs(float(time_row[1]) - (INITIAL_TIME + (index - 1) * COVARIATE_SPACING)) > PRINTED_PRECISION:
            raise SystemExit(f"covart.csv row {index}: time {time_row[1]} is off the 0.01 grid from 1891")
        rows.append([time_row[1]] + value_row[1:])
    return [["time"] + names] + rows


def write_table(path: Path, rows: list[list[str]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        csv.writer(handle, lineterminator="\n").writerows(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("wheel", type=Path, help="the pypomp wheel (pip download --no-deps pypomp)")
    parser.add_argument("--out", type=Path, default=Path("examples/data"), help="output folder")
    arguments = parser.parse_args(argv)
    with zipfile.ZipFile(arguments.wheel) as wheel:
        deaths = extracted_deaths(wheel)
        covariates = extracted_covariates(wheel)
    write_table(arguments.out / DEATHS_FILE, deaths)
    write_table(arguments.out / COVARIATES_FILE, covariates)
    print(f"{arguments.out / DEATHS_FILE}: {len(deaths) - 1} months; "
          f"{arguments.out / COVARIATES_FILE}: {len(covariates) - 1} times x {len(covariates[0]) - 1} covariates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
