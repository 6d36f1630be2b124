"""Without stage I's log the bootstrap measures its repair outlook (inceptiongs.bootstrap.probe):
photo steps first, the held-out views scored before and after them, never a virtual step before
the outlook is known."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from inceptiongs.bootstrap import loop as loop_module
from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.outlook import Outlook
from inceptiongs.bootstrap.probe import Probe, can_probe, measured_outlook, plan_probe
from inceptiongs.bootstrap.runner import resolve_targets, run_bootstrap
from inceptiongs.bootstrap.stage1 import load_stage1
from train_cases import tiny_demo_run

STEPS = 12


@pytest.fixture(scope="module")
def stage1(tmp_path_factory) -> Path:
    return tiny_demo_run(tmp_path_factory.mktemp("probe"))


@pytest.fixture
def without_log(stage1, tmp_path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(stage1, run)
    (run / "metrics.jsonl").unlink()
    return run


def _config(**overrides) -> BootstrapConfig:
    base = BootstrapConfig(seed=2, iterations=STEPS, k=2, l=2, log_every=1, save_views=0, checkpoint_every=1000,
                           regenerate_every=0, follow_outlook=True, fill="render")
    return BootstrapConfig(**{**base.__dict__, **overrides})


def _targets(run: Path):
    loaded = load_stage1(run)
    return resolve_targets(loaded.scene, loaded.split, None, None, 1)


def _records(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


def test_the_probe_is_a_share_of_the_steps_or_of_the_time_budget():
    assert plan_probe(100, 60, None, 0.0, 5.0) == Probe(110, math.inf, 5.0)
    assert plan_probe(100, 3, None, 0.0, 0.0).until_step == 102        # at least two steps
    probe = plan_probe(100, 600, 120.0, 12.0, 0.0)
    assert probe.until_s == pytest.approx(12.0 + 108.0 / 6.0)
    assert probe.over(201, 0.0) and probe.over(150, 31.0) and not probe.over(150, 29.0)


def test_two_scorings_give_the_outlook_a_log_would():
    before = {"scarce_psnr": 15.0, "covered_psnr": 22.0}
    rising = measured_outlook(before, {"scarce_psnr": 16.0, "covered_psnr": 22.5}, 60.0)
    assert rising.verdict == "train longer" and rising.scarce_db_per_min == pytest.approx(1.0)
    assert "measured" in rising.line
    flat = measured_outlook(before, {"scarce_psnr": 15.05, "covered_psnr": 22.0}, 60.0)
    assert flat.verdict == "repair"
    level = measured_outlook({"scarce_psnr": 21.5, "covered_psnr": 22.0}, {"scarce_psnr": 21.6, "covered_psnr": 22.0},
                             60.0)
    assert level.verdict == "nothing to repair"
    assert not can_probe({"all_psnr": 20.0}) and not can_probe({"scarce_psnr": float("nan"), "covered_psnr": 1.0})


def test_a_run_without_its_log_is_measured_and_takes_no_virtual_step_before(without_log, tmp_path):
    out = tmp_path / "boot"
    result = run_bootstrap(without_log, out, _targets(without_log), _config(), progress=False)
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["outlook"]["measured"] is True and summary["outlook"]["verdict"] != "unknown"
    until = summary["probe"]["until_step"]
    records = _records(out)
    probe_line = next(r for r in records if r.get("phase") == "probe")
    assert probe_line["iteration"] == until and "scarce_psnr" in probe_line
    steps = [r for r in records if "kind" in r]
    assert all(r["kind"] == "real" for r in steps if r["iteration"] <= until)
    assert len(steps) == STEPS and result.iteration == result.start_iteration + STEPS


def test_after_a_probe_that_says_repair_the_views_come(without_log, tmp_path, monkeypatch):
    monkeypatch.setattr(loop_module, "measured_outlook", lambda *args: Outlook(
        "repair", "worth a repair: (a test's probe)", gap_db=5.0))
    out = tmp_path / "boot"
    result = run_bootstrap(without_log, out, _targets(without_log), _config(), progress=False)
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    until = summary["probe"]["until_step"]
    steps = [r for r in _records(out) if "kind" in r]
    assert result.virtual_views > 0 and result.virtual_steps > 0
    assert all(r["kind"] == "real" for r in steps if r["iteration"] <= until)
    assert any(r["kind"] != "real" for r in steps if r["iteration"] > until)


def test_with_its_log_the_run_is_not_probed(stage1, tmp_path):
    out = tmp_path / "boot"
    run_bootstrap(stage1, out, _targets(stage1), _config(iterations=4), progress=False)
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert "probe" not in summary and not summary["outlook"].get("measured")
    assert not any(r.get("phase") == "probe" for r in _records(out))
