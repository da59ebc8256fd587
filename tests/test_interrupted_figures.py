"""A run stopped while it draws its figures: the folder is never "complete" with figures missing.

The tables of a finished run are written before its figures; Ctrl-C or SIGTERM (a
KeyboardInterrupt inside pfx) while the figures are drawn used to leave a manifest that said
complete, figures missing and a stale cells/ folder, and the rerun said "up to date". Now the
manifest carries ``figures_pending`` until every figure is drawn, cells/ is gone before the
manifest says complete, and a rerun (or ``pfx figures``) draws the figures.
"""

from __future__ import annotations

import importlib
import json

import pytest

import pfx
from pfx.result_folder import FIGURES_PENDING

runner = importlib.import_module("pfx.run.runner")    # `pfx.run` is also the function

FIGURES = ["error_over_time", "ess_over_time"]


def _stop_while_drawing(monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(runner, "render_figures", interrupted)


def _manifest(folder):
    return json.loads((folder / "manifest.json").read_text())


def test_a_run_stopped_while_drawing_is_finished_by_the_rerun(tmp_path, monkeypatch, tiny_config_dict, capsys):
    config = tiny_config_dict(outputs={"trace_trials": 2, "figures": FIGURES})
    out = tmp_path / "run"
    with monkeypatch.context() as patch:
        _stop_while_drawing(patch)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(config, out=out)
    manifest = _manifest(out)
    assert manifest["complete"] is True and manifest[FIGURES_PENDING] is True
    assert not (out / "cells").exists()                     # no stale cells beside complete tables
    assert not list((out / "figures").glob("*.png"))
    trials = (out / "trials.csv").read_bytes()

    pfx.run(config, out=out, quiet=False)                   # the same command again
    assert "figures drawn" in capsys.readouterr().err
    assert sorted(path.stem for path in (out / "figures").glob("*.png")) == sorted(FIGURES)
    assert FIGURES_PENDING not in _manifest(out)
    assert (out / "trials.csv").read_bytes() == trials       # the tables were kept, not recomputed

    pfx.run(config, out=out, quiet=False)                   # and now it is up to date
    assert "up to date" in capsys.readouterr().err


def test_an_extension_stopped_while_drawing_keeps_every_trial_once(tmp_path, monkeypatch, tiny_config_dict):
    out = tmp_path / "run"
    pfx.run(tiny_config_dict(trials=2), out=out)
    with monkeypatch.context() as patch:
        _stop_while_drawing(patch)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(tiny_config_dict(trials=4), out=out)
    result = pfx.run(tiny_config_dict(trials=4), out=out)
    assert sorted(result.trials["trial"]) == [0, 1, 2, 3]
    assert FIGURES_PENDING not in _manifest(out)


def test_pfx_figures_draws_what_an_interrupted_run_left(tmp_path, monkeypatch, tiny_config_dict, run_pfx):
    out = tmp_path / "run"
    with monkeypatch.context() as patch:
        _stop_while_drawing(patch)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(tiny_config_dict(outputs={"trace_trials": 2, "figures": FIGURES}), out=out)
    code, _, stderr = run_pfx("figures", out)
    assert code == 0, stderr
    assert sorted(path.stem for path in (out / "figures").glob("*.png")) == sorted(FIGURES)
    assert FIGURES_PENDING not in _manifest(out)
