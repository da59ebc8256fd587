"""What a ``pfx`` command imports: no matplotlib and no scipy.stats unless it needs them.

Importing matplotlib.pyplot and scipy.stats took about a second of the 3.4 s a tiny ``pfx run``
took, for a config that draws no figure. pfx imports them inside the functions that draw or
that compute with them, so a command that needs neither never imports them. Each command
runs in a fresh interpreter (the test process has imported both long ago), through
:func:`pfx.cli.main` as ``python -m pfx`` runs it, and prints which of the two modules it
left in ``sys.modules``. Nothing here measures time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from conftest import DEFAULT_TIMEOUT_S, REPO_ROOT, tiny_config_dict, write_config_file

HEAVY_MODULES = ("matplotlib", "scipy.stats")

# Runs pfx's entry point on the arguments in sys.argv[1:], then prints which heavy modules it imported.
PROBE = f"""
import json, sys
sys.argv = ["pfx", *sys.argv[1:]]
from pfx.cli import main
try:
    main()
except SystemExit as exit:
    if exit.code not in (0, None):
        raise
print(json.dumps([name for name in {HEAVY_MODULES!r} if name in sys.modules]))
"""


def imported_by(*arguments, cwd) -> list[str]:
    """The heavy modules a fresh ``pfx ARGUMENTS`` imported (its last line of output)."""
    environment = dict(os.environ, CI="1", MPLBACKEND="Agg",
                       PYTHONPATH=os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")])))
    completed = subprocess.run([sys.executable, "-c", PROBE, *map(str, arguments)], cwd=cwd, env=environment,
                               capture_output=True, text=True, timeout=DEFAULT_TIMEOUT_S, stdin=subprocess.DEVNULL)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    return json.loads(completed.stdout.splitlines()[-1])


def config_drawing(tmp_path, figures: list[str]):
    return write_config_file(tmp_path, tiny_config_dict(outputs={"trace_trials": 2, "figures": figures}))


@pytest.mark.parametrize("command", ["run", "validate", "list"])
def test_a_command_without_figures_imports_neither_matplotlib_nor_scipy_stats(tmp_path, command):
    config = config_drawing(tmp_path, [])
    arguments = {"run": ["run", config, "--out", tmp_path / "result", "--quiet"],
                 "validate": ["validate", config],
                 "list": ["list"]}[command]
    assert imported_by(*arguments, cwd=tmp_path) == []


def test_a_run_with_a_figure_still_draws_it(tmp_path):
    config = config_drawing(tmp_path, ["ess_over_time"])
    # matplotlib in the list also shows that the probe sees what a command imports
    assert "matplotlib" in imported_by("run", config, "--out", tmp_path / "result", "--quiet", cwd=tmp_path)
    figure = tmp_path / "result" / "figures" / "ess_over_time.png"
    assert figure.stat().st_size > 0
    assert figure.read_bytes().startswith(b"\x89PNG")
